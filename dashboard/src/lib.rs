//! Web pages, plotters charts and report exports, mounted by the scoring service.
//!
//! Empty on purpose: the dashboard issue fills it. Nothing here pretends to work yet.
