//! One module per page (or group of pages and the forms they post).

pub mod admin;
pub mod admin_atlases;
pub mod admin_lti;
pub mod benchmark;
pub mod catalogue;
pub mod cohort;
pub mod compare;
pub mod home;
pub mod instructors;
pub mod login;
pub mod lti;
pub mod pairing;
pub mod reports;
pub mod review;
pub mod sessions;
pub mod tokens;
pub mod upload;
