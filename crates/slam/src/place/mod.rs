//! Place recognition by bags of binary words: a vocabulary trained on our own rendered frames
//! ([`vocabulary`]), keyframes as tf-idf word vectors ([`bow`]), used for appearance loop
//! candidates (`loop_closing::detection`).

pub mod bow;
pub mod error;
pub mod vocabulary;

pub use bow::BowVector;
pub use error::PlaceError;
pub use vocabulary::{Vocabulary, VocabularyConfig};
