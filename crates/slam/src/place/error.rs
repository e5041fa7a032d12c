//! Errors of place recognition.

/// What can go wrong in training, reading or using a vocabulary.
#[derive(Debug, thiserror::Error)]
pub enum PlaceError {
    /// A training setting is out of its valid range.
    #[error("invalid vocabulary setting: {field} = {value} ({reason})")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// Fewer training descriptors than one node's children.
    #[error("too few descriptors to train a vocabulary: {found}, need at least {required}")]
    TooFewDescriptors { required: usize, found: usize },
    /// A vocabulary file is not in the expected format.
    #[error("corrupt vocabulary: {reason}")]
    CorruptVocabulary { reason: String },
}

/// Result alias of place recognition.
pub type Result<T, E = PlaceError> = std::result::Result<T, E>;
