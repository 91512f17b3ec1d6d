//! The force a force-feedback device was actually sent, beside the force the physics computed
//! (docs/session-format.md "Device forces"): per tick, what the device's servo loop last sent
//! when the tick read the device, and what its force guard did to it (held, the watchdog,
//! waiting to engage, ramping, clamped, the continuous limit). Metadata for the review: replay and
//! scoring never read it, since it depends on the device and the hand, not on the recorded poses.
//!
//! Stored like the tick blocks, column by column ([`crate::codec`]): up to 500 consecutive ticks
//! per message, the force as integer steps of 2⁻¹⁶ N (as the rounded tick outputs), the guard's
//! flags as one byte.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_bytes::ByteBuf;

use crate::codec;
use crate::outputs;

/// Steps per newton of the sent force (15 µN: far below what a device renders).
const STEPS_PER_N: f64 = 65536.0;
/// The most ticks one message holds.
pub const BLOCK_TICKS: usize = 500;

/// The force guard's flags as stored, one bit each.
pub mod guard {
    /// Zero: held (paused, out of focus, clutch, uncalibrated, closing).
    pub const HELD: u8 = 1 << 0;
    /// Zero: the watchdog fired (no new force from the simulation in time).
    pub const WATCHDOG: u8 = 1 << 1;
    /// Zero: waiting for a small force to engage.
    pub const WAITING: u8 = 1 << 2;
    /// Zero: the computed force was not finite.
    pub const NOT_FINITE: u8 = 1 << 3;
    /// Scaled by the ramp.
    pub const RAMPING: u8 = 1 << 4;
    /// Clamped to the device's maximum.
    pub const CLAMPED: u8 = 1 << 5;
    /// Scaled down to the continuous limit.
    pub const CONTINUOUS: u8 = 1 << 6;
    /// Every flag.
    pub const ALL: u8 = 0x7f;
}

/// One tick's force at the device.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceForceRecord {
    pub tick: u64,
    /// The force sent (N, the device's frame as Stylet's pose source turns it: x right, y away
    /// from the user, z up).
    pub sent_n: [f64; 3],
    /// [`guard`] flags.
    pub guard: u8,
}

impl DeviceForceRecord {
    /// Whether the guard zeroed this tick's force (held, watchdog, waiting, not finite).
    pub fn zeroed(&self) -> bool {
        self.guard & (guard::HELD | guard::WATCHDOG | guard::WAITING | guard::NOT_FINITE) != 0
    }

    /// Whether the guard reduced this tick's force (ramp, clamp, continuous limit).
    pub fn limited(&self) -> bool {
        self.guard & (guard::RAMPING | guard::CLAMPED | guard::CONTINUOUS) != 0
    }
}

/// The message: consecutive ticks, column by column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceForceBlock {
    pub first_tick: u64,
    pub count: u32,
    pub columns: BTreeMap<String, ByteBuf>,
}

const FORCE_COLUMNS: [&str; 3] = ["sent_x_n", "sent_y_n", "sent_z_n"];

/// The block of `records` (consecutive, 1 … [`BLOCK_TICKS`]); a force that is not finite or too
/// large to count in steps is stored as zero with the not-finite flag (the guard never sends one).
pub fn encode(records: &[DeviceForceRecord]) -> DeviceForceBlock {
    let mut columns = BTreeMap::new();
    let storable = |r: &DeviceForceRecord| r.sent_n.iter().all(|&f| outputs::steps(f, STEPS_PER_N).is_some());
    for (axis, name) in FORCE_COLUMNS.iter().enumerate() {
        let steps: Vec<i64> = records
            .iter()
            .map(|r| match storable(r) {
                true => outputs::steps(r.sent_n[axis], STEPS_PER_N).unwrap_or(0),
                false => 0,
            })
            .collect();
        columns.insert(name.to_string(), ByteBuf::from(codec::encode_i64(&steps)));
    }
    let flags: Vec<u64> = records
        .iter()
        .map(|r| u64::from((r.guard | if storable(r) { 0 } else { guard::NOT_FINITE }) & guard::ALL))
        .collect();
    columns.insert("guard".into(), ByteBuf::from(codec::encode(&flags, 1)));
    DeviceForceBlock {
        first_tick: records.first().map_or(0, |r| r.tick),
        count: records.len() as u32,
        columns,
    }
}

/// Why a device-force block cannot be decoded. A reader treats it as damage.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeviceForceError {
    #[error("device-force block of {0} ticks")]
    TickCount(u32),
    #[error("device-force block tick numbers overflow")]
    TickOverflow,
    #[error("device-force block lacks column '{0}'")]
    MissingColumn(&'static str),
    #[error("device-force column '{0}' has the wrong length")]
    ColumnLength(&'static str),
    #[error("device-force column '{0}' holds a value out of range")]
    OutOfRange(&'static str),
}

/// The records of a block; names the first problem.
pub fn decode(b: &DeviceForceBlock) -> Result<Vec<DeviceForceRecord>, DeviceForceError> {
    let n = b.count as usize;
    if n == 0 || n > BLOCK_TICKS {
        return Err(DeviceForceError::TickCount(b.count));
    }
    if b.first_tick.checked_add(n as u64).is_none() {
        return Err(DeviceForceError::TickOverflow);
    }
    let bytes = |name: &'static str| b.columns.get(name).ok_or(DeviceForceError::MissingColumn(name));
    let mut forces = Vec::with_capacity(3);
    for name in FORCE_COLUMNS {
        let steps = codec::decode_i64(bytes(name)?, n).ok_or(DeviceForceError::ColumnLength(name))?;
        let newtons = steps
            .into_iter()
            .map(|s| {
                let f = outputs::from_steps(s, STEPS_PER_N);
                (outputs::steps(f, STEPS_PER_N) == Some(s))
                    .then_some(f)
                    .ok_or(DeviceForceError::OutOfRange(name))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        forces.push(newtons);
    }
    let flags = codec::decode(bytes("guard")?, 1, n).ok_or(DeviceForceError::ColumnLength("guard"))?;
    if flags.iter().any(|&f| f > u64::from(guard::ALL)) {
        return Err(DeviceForceError::OutOfRange("guard"));
    }
    Ok((0..n)
        .map(|i| DeviceForceRecord {
            tick: b.first_tick + i as u64,
            sent_n: [forces[0][i], forces[1][i], forces[2][i]],
            guard: flags[i] as u8,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_round_trips_to_the_force_step_and_keeps_every_flag() {
        let records: Vec<DeviceForceRecord> = (0..BLOCK_TICKS as u64)
            .map(|i| DeviceForceRecord {
                tick: 1000 + i,
                sent_n: [0.001 * i as f64, -1.5, (i as f64 * 0.01).sin()],
                guard: (i % 128) as u8,
            })
            .collect();
        let back = decode(&encode(&records)).unwrap();
        assert_eq!(back.len(), records.len());
        for (a, b) in records.iter().zip(&back) {
            assert_eq!((a.tick, a.guard), (b.tick, b.guard));
            for k in 0..3 {
                assert!((a.sent_n[k] - b.sent_n[k]).abs() <= 0.5 / STEPS_PER_N);
            }
        }
        assert!(back[2].zeroed() && back[32].limited() && !back[0].zeroed() && !back[0].limited());
    }

    #[test]
    fn a_force_that_cannot_be_stored_is_zero_and_flagged() {
        let r = DeviceForceRecord {
            tick: 0,
            sent_n: [f64::NAN, 0.0, 1.0],
            guard: 0,
        };
        let back = decode(&encode(&[r])).unwrap();
        assert_eq!(back[0].sent_n, [0.0; 3]);
        assert_eq!(back[0].guard, guard::NOT_FINITE);
    }

    #[test]
    fn bad_blocks_are_named() {
        let good = encode(&[DeviceForceRecord {
            tick: 5,
            sent_n: [0.0; 3],
            guard: 0,
        }]);
        let mut b = good.clone();
        b.count = 0;
        assert_eq!(decode(&b), Err(DeviceForceError::TickCount(0)));
        let mut b = good.clone();
        b.columns.remove("sent_y_n");
        assert_eq!(decode(&b), Err(DeviceForceError::MissingColumn("sent_y_n")));
        let mut b = good.clone();
        b.count = 2;
        assert_eq!(decode(&b), Err(DeviceForceError::ColumnLength("sent_x_n")));
        let mut b = good.clone();
        b.columns.insert("guard".into(), ByteBuf::from(vec![0x80]));
        assert_eq!(decode(&b), Err(DeviceForceError::OutOfRange("guard")));
        let mut b = good;
        b.first_tick = u64::MAX;
        assert_eq!(decode(&b), Err(DeviceForceError::TickOverflow));
    }
}
