//! A small RFC 4180 reader for the CSV files a session holds (the replay's results,
//! `truth.csv`, the daemon's `estimates.csv`): fields separated by commas, records by
//! CRLF or LF; a quoted field may hold commas, doubled quotes and line breaks; a UTF-8
//! byte-order mark before the header is skipped; blank lines are skipped. Cells are
//! returned as written (quotes removed, nothing trimmed).

/// A CSV file as a header and its records.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Record>,
}

/// One record and the line it starts on (1 is the header), for messages.
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    pub line: usize,
    pub cells: Vec<String>,
}

impl Table {
    /// Reads `text`; an empty file or a quote left open is an error.
    pub fn parse(text: &str) -> Result<Table, String> {
        let mut records = records(text)?.into_iter();
        let header = records.next().ok_or("the file is empty")?.cells;
        Ok(Table {
            header,
            rows: records.collect(),
        })
    }

    /// The index of the column named `name` (surrounding spaces ignored).
    pub fn column(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h.trim() == name)
    }
}

impl Record {
    /// The trimmed cell of `column`; "" when the column or the cell is missing.
    pub fn cell(&self, column: Option<usize>) -> &str {
        column
            .and_then(|i| self.cells.get(i))
            .map_or("", |c| c.trim())
    }

    /// The cell of `column` as a finite number.
    pub fn number(&self, column: Option<usize>) -> Option<f64> {
        self.cell(column)
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
    }
}

/// Every non-blank record of `text`.
pub fn records(text: &str) -> Result<Vec<Record>, String> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut out = Vec::new();
    let mut cells = Vec::new();
    let mut field = String::new();
    let mut quoted = false;
    // The field began with a quote (so an empty quoted field still counts as a record).
    let mut had_quote = false;
    let mut line = 1;
    let mut start = 1;
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                field.push('"');
                chars.next();
            }
            ('"', true) => quoted = false,
            ('"', false) if field.is_empty() => {
                quoted = true;
                had_quote = true;
            }
            (',', false) => {
                cells.push(std::mem::take(&mut field));
                had_quote = false;
            }
            ('\r', false) if chars.peek() == Some(&'\n') => {}
            ('\n', false) => {
                cells.push(std::mem::take(&mut field));
                push_record(&mut out, std::mem::take(&mut cells), start, had_quote);
                had_quote = false;
                line += 1;
                start = line;
            }
            (c, _) => {
                if c == '\n' {
                    line += 1;
                }
                field.push(c);
            }
        }
    }
    if quoted {
        return Err(format!(
            "line {start}: a quoted field is never closed (a '\"' is missing)"
        ));
    }
    cells.push(field);
    push_record(&mut out, cells, start, had_quote);
    Ok(out)
}

/// Keeps `cells` unless the line was blank.
fn push_record(out: &mut Vec<Record>, cells: Vec<String>, line: usize, had_quote: bool) {
    let blank = cells.len() == 1 && cells[0].trim().is_empty() && !had_quote;
    if !blank {
        out.push(Record { line, cells });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cells(text: &str) -> Vec<Vec<String>> {
        records(text)
            .unwrap()
            .into_iter()
            .map(|r| r.cells)
            .collect()
    }

    #[test]
    fn rfc4180_quoting_line_breaks_and_bom() {
        let text = "\u{feff}frame,note\r\n\"a,b.png\",\"say \"\"hi\"\"\"\r\n\
                    \"two\nlines.png\",x\n\n\"\",\n";
        assert_eq!(
            cells(text),
            [
                vec!["frame", "note"],
                vec!["a,b.png", "say \"hi\""],
                vec!["two\nlines.png", "x"],
                vec!["", ""],
            ]
        );
        let lines: Vec<usize> = records(text).unwrap().iter().map(|r| r.line).collect();
        assert_eq!(
            lines,
            [1, 2, 3, 6],
            "a record starts where its first field does"
        );
        let table = Table::parse(text).unwrap();
        assert_eq!(
            table.column("note"),
            Some(1),
            "the BOM is not part of the header"
        );
        assert_eq!(table.rows[1].cell(Some(0)), "two\nlines.png");
    }

    #[test]
    fn last_record_without_newline_and_missing_cells() {
        let table = Table::parse("a,b,c\n1,,3\n4").unwrap();
        assert_eq!(table.rows.len(), 2);
        assert_eq!(table.rows[0].number(Some(1)), None);
        assert_eq!(table.rows[0].number(Some(2)), Some(3.0));
        assert_eq!(table.rows[1].cell(Some(2)), "", "missing cells read empty");
        assert_eq!(table.rows[1].number(Some(0)), Some(4.0));
    }

    #[test]
    fn non_finite_numbers_read_as_missing() {
        let table = Table::parse("v\nNaN\ninf\n-inf\n1e999\n2.5\n").unwrap();
        let read: Vec<Option<f64>> = table.rows.iter().map(|r| r.number(Some(0))).collect();
        assert_eq!(read, [None, None, None, None, Some(2.5)]);
    }

    #[test]
    fn open_quote_and_empty_file_are_errors() {
        let err = records("a,b\n1,\"open\n2,3\n").unwrap_err();
        assert!(
            err.contains("line 2") && err.contains("never closed"),
            "{err}"
        );
        assert!(Table::parse("").is_err());
        assert!(Table::parse("\u{feff}\n\n").is_err());
    }
}
