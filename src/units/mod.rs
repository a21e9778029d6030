//! Units at the edges: numbers and times as people read them ([`human`]). Inside, lengths are
//! mm and angles rad; this module is where they become text.

pub mod human;
