//! Test support shared by the workspace's test suites: fixture directories and the real CT data
//! for every crate; for the root package's end-to-end tests, the `stylet` binary ([`Stylet`]), the
//! service on SQLite or PostgreSQL ([`Db`], [`on_both_databases!`], [`Server`]), HTTP calls checked
//! against the OpenAPI document ([`call`], [`contract`]) and scored sessions ([`Fixture`],
//! [`upload_scored`]).

pub mod contract;
mod database;
mod fixture_dir;
mod http;
mod lrs;
mod lti_platform;
mod object_store;
mod real_ct;
mod scored;
mod server;
mod stylet;

pub use database::Db;
pub use fixture_dir::fixture_dir;
pub use http::{Auth, Page, call, get_bytes, login, page, raw_post, raw_post_as};
pub use lrs::{LRS_PASSWORD, LRS_USERNAME, Lrs};
pub use lti_platform::{LTI_CLIENT_ID, LTI_DEPLOYMENT_ID, LtiPlatform};
pub use object_store::S3Server;
pub use real_ct::{real_ct_data, real_ct_data_dir};
pub use scored::{Fixture, phantom_script, upload, upload_scored, wait_scored, workspace_dir};
pub use server::Server;
pub use stylet::{Stylet, s};

/// Used by [`on_both_databases!`] to name its tests.
#[doc(hidden)]
pub use pastey;
