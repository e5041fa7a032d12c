//! Learned local features and matchers (paper §III-B, DESIGN §5): SuperPoint, ALIKED, DISK,
//! XFeat, LightGlue and LighterGlue compiled from their pretrained weights to ONNX graphs.
//!
//! Stage boundary only for now: the networks arrive with issue #4.
