//! The JointLoc system (paper §III-A, §III-C): absolute fixes and SLAM poses fused inside the
//! local bundle adjustment, with an online SLAM→world Sim(3).
//!
//! Stage boundary only for now: the fusion arrives with issue #7.
