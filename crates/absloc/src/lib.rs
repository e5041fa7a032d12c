//! Absolute localisation (paper §III-B): the UAV frame is matched against satellite-map tiles,
//! a homography maps the image centre into the map, and an adaptive confidence
//! `w = SSIM × mean matching score` sets the next search radius `r = ceil(10^(1-w))`.
//!
//! Stage boundary only for now: the search arrives with issue #5.
