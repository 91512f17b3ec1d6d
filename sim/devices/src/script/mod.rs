//! The script language of the scripted device (docs/scripts.md): [`parse`] reads it, [`device`]
//! plays it tick by tick.
pub mod device;
pub mod parse;

pub use device::{NamedPath, ScriptedDevice};
pub use parse::{ParseError, Script, parse};
