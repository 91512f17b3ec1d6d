//! The script language of the scripted device (docs/scripts.md): [`parse`](mod@parse) reads it, [`device`]
//! plays it tick by tick.
pub mod device;
pub mod parse;
pub mod setup;

pub use device::{BindError, ScriptedDevice};
pub use parse::{Hand, ParseError, Script, ScriptHand, parse};
pub use setup::{SetupError, scripted_simulation};
pub use stylet_physics::PlannedPath;
