/* A stand-in for comedilib (libcomedi.so.0), built by tests/hw_fakes.rs and put first
 * on LD_LIBRARY_PATH of a child process, so nanoforce's real comedi FFI path runs
 * against it. It exports the symbols nanoforce uses (same names, same symbol versions)
 * and appends one line per call to $FAKE_COMEDI_LOG.
 *
 * The board it pretends to be ($FAKE_COMEDI_BOARD): "pci-6035e" (default) or
 * "pci-6034e" (no analog outputs). Subdevices, as ni_pcimio numbers them:
 *   0 AI, 1 AO (2 channels, 12 bits: range 0 = -10..10 V, range 1 = 0..5 V), 2 DIO (8),
 *   11 and 12 general-purpose counters (24 bits; channels 0 count, 1 load A, 2 load B).
 * Only paths starting with /fake/comedi open. $FAKE_COMEDI_FAIL_WRITES_AFTER=N makes
 * every comedi_data_write after the N-th fail with EIO. */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define FAKE_LOG_ENV "FAKE_COMEDI_LOG"
#include "fake_log.h"

typedef struct { double min; double max; unsigned int unit; } comedi_range;
typedef struct { int open; } comedi_t;

static comedi_t board;
static int last_errno;
static long writes;
static comedi_range ao_ranges[2] = {{-10.0, 10.0, 0}, {0.0, 5.0, 0}};
static comedi_range counter_range = {0.0, 16777215.0, 2};

static int no_ao(void) {
    const char *b = getenv("FAKE_COMEDI_BOARD");
    return b && strcmp(b, "pci-6034e") == 0;
}

/* comedi's subdevice types: 1 AI, 2 AO, 5 DIO, 6 counter, 0 unused. */
static int type_of(unsigned s) {
    switch (s) {
    case 0: return 1;
    case 1: return no_ao() ? 0 : 2;
    case 2: return 5;
    case 11: case 12: return 6;
    default: return s < 14 ? 0 : -1;
    }
}

static int fail(int e) { last_errno = e; return -1; }
static int bad(comedi_t *it, unsigned s) { return it != &board || !board.open || type_of(s) < 0; }

comedi_t *comedi_open(const char *path) {
    logf_("open %s", path);
    if (strncmp(path, "/fake/comedi", 12) != 0) { last_errno = ENOENT; return NULL; }
    board.open = 1;
    return &board;
}
int comedi_close(comedi_t *it) { logf_("close"); if (it != &board) return fail(EINVAL); board.open = 0; return 0; }
int comedi_errno(void) { return last_errno; }
const char *comedi_strerror(int e) { return strerror(e); }
const char *comedi_get_board_name(comedi_t *it) { (void)it; return no_ao() ? "pci-6034e" : "pci-6035e"; }
const char *comedi_get_driver_name(comedi_t *it) { (void)it; return "ni_pcimio"; }
int comedi_get_n_subdevices(comedi_t *it) { return it == &board ? 14 : fail(EINVAL); }
int comedi_get_subdevice_type(comedi_t *it, unsigned s) { return bad(it, s) ? fail(EINVAL) : type_of(s); }
int comedi_get_n_channels(comedi_t *it, unsigned s) {
    if (bad(it, s)) return fail(EINVAL);
    switch (type_of(s)) { case 1: return 16; case 2: return 2; case 5: return 8; case 6: return 3; default: return 0; }
}
unsigned comedi_get_maxdata(comedi_t *it, unsigned s, unsigned c) {
    (void)c;
    if (bad(it, s)) { last_errno = EINVAL; return 0; }
    return type_of(s) == 6 ? 0xffffff : 0xfff;
}
comedi_range *comedi_get_range(comedi_t *it, unsigned s, unsigned c, unsigned r) {
    logf_("get_range %u %u %u", s, c, r);
    if (bad(it, s)) { last_errno = EINVAL; return NULL; }
    if (type_of(s) == 6 && r == 0) return &counter_range;
    if (type_of(s) != 2 || c >= 2 || r >= 2) { last_errno = EINVAL; return NULL; }
    return &ao_ranges[r];
}
int comedi_find_range(comedi_t *it, unsigned s, unsigned c, unsigned unit, double min, double max) {
    logf_("find_range %u %u %u %g %g", s, c, unit, min, max);
    if (bad(it, s) || type_of(s) != 2) return fail(EINVAL);
    for (int r = 0; r < 2; r++)
        if (ao_ranges[r].unit == unit && ao_ranges[r].min <= min && ao_ranges[r].max >= max) return r;
    return fail(EINVAL);
}
/* comedilib's own linear conversion. */
unsigned comedi_from_phys(double data, comedi_range *rng, unsigned maxdata) {
    if (!rng) return 0;
    double s = (data - rng->min) / (rng->max - rng->min) * maxdata;
    if (s < 0) return 0;
    if (s > maxdata) return maxdata;
    return (unsigned)(s + 0.5);
}
int comedi_data_write(comedi_t *it, unsigned s, unsigned c, unsigned r, unsigned aref, unsigned data) {
    const char *limit = getenv("FAKE_COMEDI_FAIL_WRITES_AFTER");
    writes++;
    if (limit && writes > atol(limit)) { logf_("data_write %u %u FAILED", s, c); return fail(EIO); }
    logf_("data_write %u %u %u %u %u", s, c, r, aref, data);
    if (bad(it, s) || (type_of(s) != 2 && type_of(s) != 6)) return fail(EINVAL);
    return 1;
}
int comedi_dio_config(comedi_t *it, unsigned s, unsigned c, unsigned dir) {
    logf_("dio_config %u %u %u", s, c, dir);
    return bad(it, s) || type_of(s) != 5 || c >= 8 ? fail(EINVAL) : 1;
}
int comedi_dio_write(comedi_t *it, unsigned s, unsigned c, unsigned bit) {
    logf_("dio_write %u %u %u", s, c, bit);
    return bad(it, s) || type_of(s) != 5 || c >= 8 ? fail(EINVAL) : 1;
}
static int counter_call(const char *name, comedi_t *it, unsigned s, unsigned a, unsigned b, unsigned c) {
    logf_("%s %u %u %u %u", name, s, a, b, c);
    return bad(it, s) || type_of(s) != 6 ? fail(EINVAL) : 0;
}
int comedi_reset(comedi_t *it, unsigned s) { return counter_call("reset", it, s, 0, 0, 0); }
int comedi_arm(comedi_t *it, unsigned s, unsigned src) { return counter_call("arm", it, s, src, 0, 0); }
int comedi_disarm(comedi_t *it, unsigned s) { return counter_call("disarm", it, s, 0, 0, 0); }
int comedi_set_counter_mode(comedi_t *it, unsigned s, unsigned c, unsigned mode) {
    return counter_call("set_counter_mode", it, s, c, mode, 0);
}
int comedi_set_clock_source(comedi_t *it, unsigned s, unsigned c, unsigned clock, unsigned period_ns) {
    return counter_call("set_clock_source", it, s, c, clock, period_ns);
}
int comedi_set_gate_source(comedi_t *it, unsigned s, unsigned c, unsigned gate, unsigned source) {
    /* E-series counters have one gate: the second fails, as on the real board. */
    if (gate > 0) { logf_("set_gate_source %u %u %u %u", s, c, gate, source); return fail(EINVAL); }
    return counter_call("set_gate_source", it, s, c, gate, source);
}
