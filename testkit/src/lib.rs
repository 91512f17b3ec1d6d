//! Test support shared by the workspace's test suites.

mod fixture_dir;

pub use fixture_dir::fixture_dir;
