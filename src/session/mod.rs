//! Recorded sessions on disk (the layout of docs/conventions.md): listing and decoding
//! the frames of a folder, the SEM's scale metadata in TIFF frames, the results CSV that
//! `replay` writes and `score` reads, scoring results against a session's truth, and the
//! small RFC 4180 reader every session CSV is read through.
pub mod csv;
pub mod frames;
pub mod live;
pub mod metadata;
pub mod results;
pub mod score;
pub mod utc;
