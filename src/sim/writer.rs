//! MCAP output of the twin: hand-written little-endian CDR (XCDR1) encoders for the four fixed
//! `unitree_hg` message types the G1 records, and an MCAP writer with the `ros2` profile, embedded
//! `ros2msg` schemas, zstd chunks, chunk/message indexes and statistics — the same container layout
//! as the shared recordings (see `shared/recordings/README.md`).

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use anyhow::{Context, Result};

/// Number of motor slots in `LowState.motor_state` / `LowCmd.motor_cmd`.
pub const N_MOTORS: usize = 35;

/// The standard ROS 2 concatenated schema text: the root type's .msg text, then for each
/// dependency a line of 80 `=`, `MSG: pkg/Type` and its text.
/// Texts come from the definitions built into the reader (`read::msgdef::builtin_definition`).
fn ros2msg_schema(root: &str, deps: &[&str]) -> Result<String> {
    let text = |ty: &str| {
        crate::read::msgdef::builtin_definition(ty)
            .with_context(|| format!("no built-in message definition for {ty}"))
    };
    let mut s = String::with_capacity(2048);
    s.push_str(text(root)?.trim_end());
    s.push('\n');
    for name in deps {
        let text = text(name)?;
        s.push_str(&"=".repeat(80));
        s.push_str("\nMSG: ");
        s.push_str(name);
        s.push('\n');
        s.push_str(text.trim_end());
        s.push('\n');
    }
    Ok(s)
}

/// Little-endian XCDR1 serializer into a reusable fixed buffer (the four message types are at
/// most 2092 bytes). Alignment is relative to the start of the body (after the 4-byte
/// encapsulation header), as CDR requires.
pub struct Cdr {
    buf: Box<[u8; Cdr::CAPACITY]>,
    len: usize,
}

impl Default for Cdr {
    fn default() -> Self {
        Cdr {
            buf: Box::new([0; Cdr::CAPACITY]),
            len: 0,
        }
    }
}

/// `fn T(&mut self, v: T)` for each number type `T`: `v` little-endian at its own alignment.
macro_rules! aligned_putters {
    ($($t:ident),*) => {$(
        #[inline(always)]
        fn $t(&mut self, v: $t) {
            self.align(std::mem::size_of::<$t>());
            self.put(v.to_le_bytes());
        }
    )*};
}

impl Cdr {
    const HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
    const CAPACITY: usize = 4096;

    fn start(&mut self) {
        self.buf[..4].copy_from_slice(&Self::HEADER);
        self.len = 4;
    }
    #[inline(always)]
    fn put<const N: usize>(&mut self, bytes: [u8; N]) {
        self.buf[self.len..self.len + N].copy_from_slice(&bytes);
        self.len += N;
    }
    #[inline(always)]
    fn align(&mut self, n: usize) {
        let pad = (n - (self.len - 4) % n) % n;
        self.buf[self.len..self.len + pad].fill(0);
        self.len += pad;
    }
    #[inline(always)]
    fn u8(&mut self, v: u8) {
        self.put([v]);
    }
    aligned_putters!(u16, i16, u32, i32, f32);
    /// Append the CRC field: zlib CRC-32 of the body before it (the shared files' convention).
    fn crc(&mut self) {
        self.align(4);
        let crc = crc32fast::hash(&self.buf[4..self.len]);
        self.put(crc.to_le_bytes());
    }
    /// The encoded message (header + body).
    pub fn bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

/// One motor slot of `LowState`.
#[derive(Debug, Clone, Copy, Default)]
pub struct MotorState {
    /// 1 = servo on, 0 = unused slot.
    pub mode: u8,
    /// Position [rad].
    pub q: f32,
    /// Velocity [rad/s].
    pub dq: f32,
    /// Estimated torque [Nm].
    pub tau_est: f32,
    /// Winding and housing temperature [°C].
    pub temperature: [i16; 2],
    /// Bus voltage [V].
    pub vol: f32,
}

/// Pelvis IMU fields of `LowState`.
#[derive(Debug, Clone, Copy, Default)]
pub struct ImuState {
    /// Orientation (w, x, y, z).
    pub quaternion: [f32; 4],
    /// Angular velocity [rad/s].
    pub gyroscope: [f32; 3],
    /// Specific force [m/s²].
    pub accelerometer: [f32; 3],
    /// Roll, pitch, yaw [rad].
    pub rpy: [f32; 3],
    /// IMU temperature [°C].
    pub temperature: i16,
}

impl Cdr {
    /// Encode a `unitree_hg/msg/LowState`.
    pub fn low_state(
        &mut self,
        tick: u32,
        imu: &ImuState,
        motors: &[MotorState; N_MOTORS],
    ) -> &[u8] {
        self.start();
        self.u32(0); // version[0]
        self.u32(1); // version[1]
        self.u8(0); // mode_pr
        self.u8(5); // mode_machine (G1 29-DoF)
        self.u32(tick);
        for v in imu
            .quaternion
            .iter()
            .chain(&imu.gyroscope)
            .chain(&imu.accelerometer)
            .chain(&imu.rpy)
        {
            self.f32(*v);
        }
        self.i16(imu.temperature);
        for m in motors {
            self.u8(m.mode);
            self.f32(m.q);
            self.f32(m.dq);
            self.f32(0.0); // ddq: not provided by the robot
            self.f32(m.tau_est);
            self.i16(m.temperature[0]);
            self.i16(m.temperature[1]);
            self.f32(m.vol);
            for _ in 0..2 + 1 + 4 {
                self.u32(0); // sensor[2], motorstate, reserve[4]
            }
        }
        self.put([0u8; 40]); // wireless_remote
        for _ in 0..4 {
            self.u32(0);
        }
        self.crc();
        self.bytes()
    }

    /// Encode a `unitree_hg/msg/LowCmd` for the arm SDK: the 7 slots starting at `arm_base` carry
    /// `q`/`dq` with the PD gains, slot 29 carries the arm_sdk weight 1.0.
    pub fn low_cmd(
        &mut self,
        arm_base: usize,
        q: &[f64; 7],
        dq: &[f64; 7],
        kp: f32,
        kd: f32,
    ) -> &[u8] {
        self.start();
        self.u8(0);
        self.u8(5);
        for k in 0..N_MOTORS {
            let arm = k.checked_sub(arm_base).filter(|&i| i < 7);
            match arm {
                Some(i) => {
                    self.u8(1);
                    self.f32(q[i] as f32);
                    self.f32(dq[i] as f32);
                    self.f32(0.0);
                    self.f32(kp);
                    self.f32(kd);
                }
                None => {
                    self.u8(0);
                    self.f32(if k == ARM_SDK_WEIGHT_SLOT { 1.0 } else { 0.0 });
                    for _ in 0..4 {
                        self.f32(0.0);
                    }
                }
            }
            self.u32(0);
        }
        for _ in 0..4 {
            self.u32(0);
        }
        self.crc();
        self.bytes()
    }

    /// Encode a `unitree_hg/msg/MainBoardState` (value[0] = rail voltage [V], value[1] = current [A]).
    pub fn main_board_state(
        &mut self,
        volts: f32,
        amps: f32,
        fan_rpm: [u16; 2],
        temps: [i16; 2],
    ) -> &[u8] {
        self.start();
        for v in [fan_rpm[0], fan_rpm[1], 0, 0, 0, 0] {
            self.u16(v);
        }
        for v in [temps[0], temps[1], 0, 0, 0, 0] {
            self.i16(v);
        }
        for v in [volts, amps, 0.0, 0.0, 0.0, 0.0] {
            self.f32(v);
        }
        for _ in 0..6 {
            self.u32(0);
        }
        self.bytes()
    }

    /// Encode a `unitree_hg/msg/BmsState` (pack voltage [mV], discharge current [mA]).
    pub fn bms_state(&mut self, b: &BmsFields) -> &[u8] {
        self.start();
        self.u8(1);
        self.u8(3);
        self.u8(0);
        for k in 0..40 {
            self.u16(if k < b.cell_mv.len() { b.cell_mv[k] } else { 0 });
        }
        self.u32(b.pack_mv);
        self.u32(0);
        self.u32(0);
        self.i32(b.current_ma);
        self.u8(b.soc_pct);
        self.u8(97);
        for k in 0..12 {
            self.i16(if k < 4 { b.temps_c[k] } else { 0 });
        }
        self.u16(58); // cycle
        self.u16(2507); // manufacturer_date
        for _ in 0..5 + 3 {
            self.u32(0);
        }
        self.bytes()
    }
}

/// Slot of `LowCmd.motor_cmd` whose `q` is the arm_sdk blending weight.
pub const ARM_SDK_WEIGHT_SLOT: usize = 29;

/// Variable fields of a `BmsState` reading.
#[derive(Debug, Clone, Copy)]
pub struct BmsFields {
    /// Pack voltage [mV].
    pub pack_mv: u32,
    /// Discharge current [mA], positive when discharging.
    pub current_ma: i32,
    /// State of charge [%].
    pub soc_pct: u8,
    /// Pack temperatures [°C].
    pub temps_c: [i16; 4],
    /// Cell voltages [mV] (13 cells).
    pub cell_mv: [u16; 13],
}

/// Topics the twin writes, in channel order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topic {
    /// `/lowstate` (LowState, 100 Hz).
    LowState = 0,
    /// `/arm_sdk` (LowCmd, 100 Hz).
    ArmSdk = 1,
    /// `/lf/bmsstate` (BmsState, ~1 Hz).
    Bms = 2,
    /// `/lf/mainboardstate` (MainBoardState, ~1 Hz).
    Mbs = 3,
}

/// Topic names and type names, indexed by [`Topic`].
pub const TOPICS: [(&str, &str); 4] = [
    ("/lowstate", "unitree_hg/msg/LowState"),
    ("/arm_sdk", "unitree_hg/msg/LowCmd"),
    ("/lf/bmsstate", "unitree_hg/msg/BmsState"),
    ("/lf/mainboardstate", "unitree_hg/msg/MainBoardState"),
];

/// MCAP writer for the four G1 topics with sequence numbers and message counts per channel.
pub struct McapOut<W: Write + Seek> {
    inner: mcap::Writer<W>,
    channels: [u16; 4],
    counts: [u64; 4],
}

impl<W: Write + Seek> McapOut<W> {
    /// Start an MCAP file on `w`: header (profile `ros2`), schemas and channels.
    pub fn new(w: W) -> Result<Self> {
        let opts = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!(
                "g1viz/",
                env!("CARGO_PKG_VERSION"),
                "; mcap-rs 0.26"
            ))
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(1)
            // One background zstd worker: overlaps compression with simulation, and zstd's
            // multi-threaded output is identical for any worker count ≥ 1 (deterministic files).
            .compression_threads(1)
            .chunk_size(Some(4 * 1024 * 1024));
        let mut inner = opts.create(w).context("starting MCAP output")?;
        let schemas = [
            ros2msg_schema(
                TOPICS[0].1,
                &["unitree_hg/IMUState", "unitree_hg/MotorState"],
            )?,
            ros2msg_schema(TOPICS[1].1, &["unitree_hg/MotorCmd"])?,
            ros2msg_schema(TOPICS[2].1, &[])?,
            ros2msg_schema(TOPICS[3].1, &[])?,
        ];
        let mut channels = [0u16; 4];
        for (k, ((topic, ty), text)) in TOPICS.iter().zip(&schemas).enumerate() {
            let sid = inner
                .add_schema(ty, "ros2msg", text.as_bytes())
                .context("writing MCAP schema")?;
            channels[k] = inner
                .add_channel(sid, topic, "cdr", &BTreeMap::new())
                .context("writing MCAP channel")?;
        }
        Ok(McapOut {
            inner,
            channels,
            counts: [0; 4],
        })
    }

    /// Write one message with log_time = publish_time = `time_ns`.
    pub fn write(&mut self, topic: Topic, time_ns: u64, data: &[u8]) -> Result<()> {
        let k = topic as usize;
        let header = mcap::records::MessageHeader {
            channel_id: self.channels[k],
            sequence: self.counts[k] as u32,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.inner
            .write_to_known_channel(&header, data)
            .context("writing MCAP message")?;
        self.counts[k] += 1;
        Ok(())
    }

    /// Messages written per topic, indexed by [`Topic`].
    pub fn counts(&self) -> [u64; 4] {
        self.counts
    }

    /// Write the summary section and the footer.
    pub fn finish(mut self) -> Result<[u64; 4]> {
        self.inner.finish().context("finishing MCAP output")?;
        Ok(self.counts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn message_sizes_match_the_shared_recordings() {
        // Sizes of the messages in shared/recordings/g1_smoke.mcap (written by an independent CDR encoder).
        let mut c = Cdr::default();
        assert_eq!(
            c.low_state(1, &ImuState::default(), &[MotorState::default(); N_MOTORS])
                .len(),
            2092
        );
        assert_eq!(c.low_cmd(15, &[0.0; 7], &[0.0; 7], 400.0, 12.0).len(), 1004);
        assert_eq!(c.main_board_state(53.0, 2.0, [0, 0], [0, 0]).len(), 76);
        let b = BmsFields {
            pack_mv: 0,
            current_ma: 0,
            soc_pct: 0,
            temps_c: [0; 4],
            cell_mv: [0; 13],
        };
        assert_eq!(c.bms_state(&b).len(), 168);
    }

    #[test]
    fn idle_arm_command_matches_the_shared_crc() {
        // The idle /arm_sdk message of g1_smoke.mcap (all arm q = 0) carries crc 1264000752.
        let mut c = Cdr::default();
        let bytes = c.low_cmd(15, &[0.0; 7], &[0.0; 7], 400.0, 12.0);
        let crc = u32::from_le_bytes(bytes[bytes.len() - 4..].try_into().unwrap());
        assert_eq!(crc, 1_264_000_752);
    }
}
