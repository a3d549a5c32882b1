//! Recorded sessions on disk (scene.md's layout): listing and decoding the frames of a
//! folder, and the results CSV that `replay` writes and `score.py` reads.
pub mod frames;
pub mod results;
