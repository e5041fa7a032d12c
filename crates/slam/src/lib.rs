//! Relative localisation (paper §III-C): ORB-SLAM2-style monocular SLAM whose local bundle
//! adjustment accepts confidence-weighted global-position factors.
//!
//! Stage boundary only for now: tracking and mapping arrive with issue #6.
