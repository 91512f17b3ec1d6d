//! The bendable needle (thesis §3.5, docs/physics.md): needle types ([`spec`]), the rod model
//! ([`beam`]), the insertion channel ([`path`]), the node tangents ([`tangents`]) and one haptic
//! tick ([`tool`]).
pub mod beam;
pub mod path;
pub mod spec;
pub mod tangents;
pub mod tool;
