//! The frames: protocol constants, the [`Frame`] trait and each frame type's payload
//! layout (the tables in the [module docs](super)). Plain data and codes only: the drive
//! types are the [drive adapter's](super::drive_adapter) business.

use super::session::LinkStats;
use super::wire::{EncodeError, LinkError, PROTOCOL_VERSION, Reader, Writer, duty_ok};
use crate::algorithms::motion::Move;

/// Bytes of the CRC after the payload (CRC-16, little-endian).
pub const CRC_LEN: usize = 2;

/// [`SensorFrame`] command flag: the drive should run (clear: disable).
pub const SENSOR_FLAG_ENABLE: u8 = 1 << 0;
/// [`SensorFrame`] command flag: clear latched faults (hold it for one frame).
pub const SENSOR_FLAG_CLEAR_FAULTS: u8 = 1 << 1;
/// [`SensorFrame`] command flag: the move fields hold a move to queue
/// ([`SensorFrame::move_to`]); clear: they are zero bytes.
pub const SENSOR_FLAG_MOVE: u8 = 1 << 2;
const SENSOR_FLAGS_KNOWN: u8 = SENSOR_FLAG_ENABLE | SENSOR_FLAG_CLEAR_FAULTS | SENSOR_FLAG_MOVE;

/// [`ActuationFrame`] flag: the bridge is enabled.
pub const ACTUATION_FLAG_BRIDGE_ENABLED: u8 = 1 << 0;
/// [`ActuationFrame`] flag: the estimate fields hold an estimate.
pub const ACTUATION_FLAG_ESTIMATE_VALID: u8 = 1 << 1;
/// [`ActuationFrame`] flag: the position fields hold a [`PositionReport`] (a
/// positioning drive); clear: they are zero bytes.
pub const ACTUATION_FLAG_POSITION_VALID: u8 = 1 << 2;
/// [`ActuationFrame`] flag: the positioning drive's move queue is empty and no move is
/// active ([`PositionReport::idle`]); only with [`ACTUATION_FLAG_POSITION_VALID`].
pub const ACTUATION_FLAG_MOTION_IDLE: u8 = 1 << 3;
const ACTUATION_FLAGS_KNOWN: u8 = ACTUATION_FLAG_BRIDGE_ENABLED
    | ACTUATION_FLAG_ESTIMATE_VALID
    | ACTUATION_FLAG_POSITION_VALID
    | ACTUATION_FLAG_MOTION_IDLE;

/// Drive-state codes the frames carry are `0..STATE_CODES` (8: disabled, calibrating,
/// starting, running, fault, reacquiring, low speed, commissioning; the drive's
/// `DriveState::code`); any other code is rejected as [`LinkError::Value`].
pub const STATE_CODES: u8 = 8;

/// Wire length of a raw frame shorter than 254 bytes: one COBS overhead byte and the
/// delimiter.
pub(super) const fn wire_len(raw_len: usize) -> usize {
    raw_len + 2
}

/// Seals [`Frame`]: the link's frame types implement it, here and in `board`.
pub(super) mod private {
    /// The seal.
    pub trait Sealed {}
    impl Sealed for super::SensorFrame {}
    impl Sealed for super::ActuationFrame {}
    impl Sealed for super::CommissioningRequest {}
    impl Sealed for super::CommissioningReport {}
}

/// A frame type of the link: [`SensorFrame`], [`ActuationFrame`] or one of the board
/// link's (sealed).
pub trait Frame: private::Sealed + Sized {
    /// Payload length (bytes), before the CRC.
    const PAYLOAD_LEN: usize;
    /// Raw length (bytes): payload and CRC.
    const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes): COBS-encoded raw frame and the `0x00` delimiter.
    const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    /// Writes the payload into `payload` (exactly [`Frame::PAYLOAD_LEN`] bytes).
    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError>;

    /// Reads a payload of exactly [`Frame::PAYLOAD_LEN`] bytes whose CRC was checked.
    fn read_payload(payload: &[u8]) -> Result<Self, LinkError>;
}

/// Host → controller, once per PWM period: the plant's sensors and the commands.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorFrame {
    /// Sequence number, incremented (wrapping) by the host for each frame.
    pub sequence: u16,
    /// Phase-a current (A), finite.
    pub i_a: f32,
    /// Phase-b current (A), finite.
    pub i_b: f32,
    /// Phase-c current (A), finite.
    pub i_c: f32,
    /// DC-bus voltage (V), finite.
    pub vdc: f32,
    /// Speed reference (m/s), finite.
    pub speed_ref: f32,
    /// Command: the drive should run; clear: disable (bridge off).
    pub enable: bool,
    /// Command: clear latched faults; send it for one frame.
    pub clear_faults: bool,
    /// Command: queue this move (target m, dwell s; both finite) on a positioning drive
    /// before the step ([`Drive::push_move`](crate::drive::Drive::push_move)); send it
    /// with one frame. `None`: no move.
    pub move_to: Option<Move>,
}

impl SensorFrame {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 32;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    fn flags(&self) -> u8 {
        let mut flags = 0;
        if self.enable {
            flags |= SENSOR_FLAG_ENABLE;
        }
        if self.clear_faults {
            flags |= SENSOR_FLAG_CLEAR_FAULTS;
        }
        if self.move_to.is_some() {
            flags |= SENSOR_FLAG_MOVE;
        }
        flags
    }
}

/// Reads a move's fields (target m, dwell s, 8 bytes): the move when `present` (both
/// finite), else `None`, and then the fields must be zero bytes. Shared by
/// [`SensorFrame`] and the board link's [`BoardCommand`](super::board::BoardCommand).
pub(super) fn read_move(present: bool, r: &mut Reader<'_>) -> Result<Option<Move>, LinkError> {
    let bytes = r.bytes::<8>();
    if !present {
        return if bytes.iter().any(|&b| b != 0) { Err(LinkError::Value) } else { Ok(None) };
    }
    let mut m = Reader::new(&bytes, 8)?;
    Ok(Some(Move { target_m: m.finite_f32()?, dwell_s: m.finite_f32()? }))
}

impl Frame for SensorFrame {
    const PAYLOAD_LEN: usize = SensorFrame::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let floats = [self.i_a, self.i_b, self.i_c, self.vdc, self.speed_ref];
        let m = self.move_to.unwrap_or(Move { target_m: 0.0, dwell_s: 0.0 });
        if !floats.iter().chain(&[m.target_m, m.dwell_s]).all(|x| x.is_finite()) {
            return Err(EncodeError::InvalidValue);
        }
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        for x in floats {
            w.f32(x);
        }
        w.u8(self.flags());
        w.f32(m.target_m);
        w.f32(m.dwell_s);
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let i_a = r.finite_f32()?;
        let i_b = r.finite_f32()?;
        let i_c = r.finite_f32()?;
        let vdc = r.finite_f32()?;
        let speed_ref = r.finite_f32()?;
        let flags = r.u8();
        if flags & !SENSOR_FLAGS_KNOWN != 0 {
            return Err(LinkError::Flags);
        }
        let move_to = read_move(flags & SENSOR_FLAG_MOVE != 0, &mut r)?;
        Ok(SensorFrame {
            sequence,
            i_a,
            i_b,
            i_c,
            vdc,
            speed_ref,
            enable: flags & SENSOR_FLAG_ENABLE != 0,
            clear_faults: flags & SENSOR_FLAG_CLEAR_FAULTS != 0,
            move_to,
        })
    }
}

/// The estimator's output as sent in an [`ActuationFrame`] (SI units).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EstimateReport {
    /// Estimated electrical angle θ̂ (rad, `[-π, π)` from the drive), finite.
    pub theta_hat: f32,
    /// Estimated linear speed (m/s), finite.
    pub speed: f32,
    /// Estimated mover flux, α component (Wb), finite.
    pub psi_alpha: f32,
    /// Estimated mover flux, β component (Wb), finite.
    pub psi_beta: f32,
}

impl EstimateReport {
    pub(super) fn is_finite(&self) -> bool {
        [self.theta_hat, self.speed, self.psi_alpha, self.psi_beta].iter().all(|x| x.is_finite())
    }
}

/// A positioning drive's position and motion as sent in an [`ActuationFrame`] (SI).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PositionReport {
    /// Estimated mover position x̂ (m, the drive's `position_m`), finite.
    pub x_hat_m: f32,
    /// The motion profile's reference position (m), finite.
    pub x_ref_m: f32,
    /// The motion profile's reference speed (m/s), finite.
    pub v_ref_m_per_s: f32,
    /// Moves waiting in the drive's queue, not counting the active one.
    pub moves_queued: u8,
    /// No move is active or queued (the reference is at rest).
    pub idle: bool,
    /// Moves the controller refused since it started (full queue, target outside the
    /// stroke, bad dwell), wrapping.
    pub moves_rejected: u16,
}

impl PositionReport {
    /// Bytes of the position fields in a frame (the idle flag travels in the flags byte).
    pub(super) const WIRE_LEN: usize = 15;

    pub(super) fn is_finite(&self) -> bool {
        [self.x_hat_m, self.x_ref_m, self.v_ref_m_per_s].iter().all(|x| x.is_finite())
    }

    /// The flag bits `report` sets: [`ACTUATION_FLAG_POSITION_VALID`], and
    /// [`ACTUATION_FLAG_MOTION_IDLE`] when idle. Shared by the HIL and the board link.
    pub(super) fn flags(report: Option<Self>) -> u8 {
        match report {
            Some(p) if p.idle => ACTUATION_FLAG_POSITION_VALID | ACTUATION_FLAG_MOTION_IDLE,
            Some(_) => ACTUATION_FLAG_POSITION_VALID,
            None => 0,
        }
    }

    /// Writes the position fields of `report` (zero bytes for `None`).
    pub(super) fn write(report: Option<Self>, w: &mut Writer<'_>) {
        let p = report.unwrap_or_default();
        for x in [p.x_hat_m, p.x_ref_m, p.v_ref_m_per_s] {
            w.f32(x);
        }
        w.u8(p.moves_queued);
        w.u16(p.moves_rejected);
    }

    /// Reads the position fields under `flags`: a report with the position flag (every
    /// value finite), none without it, and then the fields must be zero bytes and the
    /// idle flag clear.
    pub(super) fn read(flags: u8, r: &mut Reader<'_>) -> Result<Option<Self>, LinkError> {
        let bytes = r.bytes::<{ PositionReport::WIRE_LEN }>();
        if flags & ACTUATION_FLAG_POSITION_VALID == 0 {
            return if flags & ACTUATION_FLAG_MOTION_IDLE != 0 || bytes.iter().any(|&b| b != 0) {
                Err(LinkError::Value)
            } else {
                Ok(None)
            };
        }
        let mut p = Reader::new(&bytes, PositionReport::WIRE_LEN)?;
        Ok(Some(PositionReport {
            x_hat_m: p.finite_f32()?,
            x_ref_m: p.finite_f32()?,
            v_ref_m_per_s: p.finite_f32()?,
            moves_queued: p.u8(),
            idle: flags & ACTUATION_FLAG_MOTION_IDLE != 0,
            moves_rejected: p.u16(),
        }))
    }
}

/// Controller → host, the answer to one [`SensorFrame`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ActuationFrame {
    /// Sequence number of the sensor frame this answers.
    pub sequence: u16,
    /// Phase-a upper-switch duty for the next period, `[0, 1]`.
    pub duty_a: f32,
    /// Phase-b upper-switch duty for the next period, `[0, 1]`.
    pub duty_b: f32,
    /// Phase-c upper-switch duty for the next period, `[0, 1]`.
    pub duty_c: f32,
    /// `false`: every switch must be off.
    pub bridge_enabled: bool,
    /// The drive's state after the step: its code, `0..`[`STATE_CODES`] (the drive
    /// adapter converts: `ActuationFrame::state`).
    pub state_code: u8,
    /// Latched faults as bits (unknown bits are kept; the drive adapter converts:
    /// `ActuationFrame::faults`).
    pub fault_bits: u16,
    /// The estimator's output, `None` while it is not running.
    pub estimate: Option<EstimateReport>,
    /// The controller's counts of dropped frames.
    pub stats: LinkStats,
    /// A positioning drive's position and motion; `None` for a speed drive.
    pub position: Option<PositionReport>,
}

impl ActuationFrame {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 56;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    fn flags(&self) -> u8 {
        let mut flags = 0;
        if self.bridge_enabled {
            flags |= ACTUATION_FLAG_BRIDGE_ENABLED;
        }
        if self.estimate.is_some() {
            flags |= ACTUATION_FLAG_ESTIMATE_VALID;
        }
        flags | PositionReport::flags(self.position)
    }
}

/// `true` for a known drive-state code (`0..STATE_CODES`).
pub(super) const fn state_code_ok(code: u8) -> bool {
    code < STATE_CODES
}

impl Frame for ActuationFrame {
    const PAYLOAD_LEN: usize = ActuationFrame::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let duties = [self.duty_a, self.duty_b, self.duty_c];
        if !duties.iter().all(|&d| duty_ok(d))
            || !self.estimate.is_none_or(|e| e.is_finite())
            || !self.position.is_none_or(|p| p.is_finite())
            || !state_code_ok(self.state_code)
        {
            return Err(EncodeError::InvalidValue);
        }
        let e = self.estimate.unwrap_or_default();
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        for d in duties {
            w.f32(d);
        }
        w.u8(self.flags());
        w.u8(self.state_code);
        w.u16(self.fault_bits);
        for x in [e.theta_hat, e.speed, e.psi_alpha, e.psi_beta] {
            w.f32(x);
        }
        w.u16(self.stats.malformed);
        w.u16(self.stats.bad_crc);
        w.u16(self.stats.out_of_order);
        PositionReport::write(self.position, &mut w);
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let duty_a = r.duty()?;
        let duty_b = r.duty()?;
        let duty_c = r.duty()?;
        let flags = r.u8();
        if flags & !ACTUATION_FLAGS_KNOWN != 0 {
            return Err(LinkError::Flags);
        }
        let state_code = r.u8();
        if !state_code_ok(state_code) {
            return Err(LinkError::Value);
        }
        let fault_bits = r.u16();
        let estimate_bytes = r.bytes::<16>();
        let estimate = if flags & ACTUATION_FLAG_ESTIMATE_VALID != 0 {
            let mut e = Reader::new(&estimate_bytes, 16)?;
            Some(EstimateReport {
                theta_hat: e.finite_f32()?,
                speed: e.finite_f32()?,
                psi_alpha: e.finite_f32()?,
                psi_beta: e.finite_f32()?,
            })
        } else if estimate_bytes.iter().any(|&b| b != 0) {
            return Err(LinkError::Value);
        } else {
            None
        };
        let stats = LinkStats { malformed: r.u16(), bad_crc: r.u16(), out_of_order: r.u16() };
        let position = PositionReport::read(flags, &mut r)?;
        Ok(ActuationFrame {
            sequence,
            duty_a,
            duty_b,
            duty_c,
            bridge_enabled: flags & ACTUATION_FLAG_BRIDGE_ENABLED != 0,
            state_code,
            fault_bits,
            estimate,
            stats,
            position,
        })
    }
}

/// [`CommissioningRequest`] action: only report the commissioning's status.
pub const COMMISSIONING_QUERY: u8 = 0;
/// [`CommissioningRequest`] action: start commissioning with the request's settings.
pub const COMMISSIONING_START: u8 = 1;

/// Host → controller, outside the control periods: start commissioning, or ask how it
/// stands. Answered by one [`CommissioningReport`] with the same sequence number. Its
/// sequence number is the requester's own (echoed, not checked against the sensor
/// frames'); the drive does not step on it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommissioningRequest {
    /// Sequence number, echoed in the report.
    pub sequence: u16,
    /// `Some(settings)`: start commissioning with what the drive is told (ratings, bus,
    /// pole pitch; SI, each finite); `None`: a query.
    pub start: Option<crate::drive::CommissioningConfig>,
}

impl CommissioningRequest {
    /// Payload length (bytes): 20 of fields and a reserved zero byte, which keeps the
    /// length apart from the board link's [`BoardCommand`](super::board::BoardCommand) (20
    /// bytes): a board-link host paired with a HIL image by mistake cannot start a
    /// commissioning.
    pub const PAYLOAD_LEN: usize = 21;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);
}

impl Frame for CommissioningRequest {
    const PAYLOAD_LEN: usize = CommissioningRequest::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        let (action, values) = match self.start {
            Some(c) => (COMMISSIONING_START, [c.rated_current_a, c.rated_voltage_v, c.bus_v, c.pole_pitch_m]),
            None => (COMMISSIONING_QUERY, [0.0; 4]),
        };
        if !values.iter().all(|x| x.is_finite()) {
            return Err(EncodeError::InvalidValue);
        }
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        w.u8(action);
        for x in values {
            w.f32(x);
        }
        w.u8(0);
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let action = r.u8();
        let values = [r.finite_f32()?, r.finite_f32()?, r.finite_f32()?, r.finite_f32()?];
        if r.u8() != 0 {
            return Err(LinkError::Value);
        }
        let start = match action {
            COMMISSIONING_START => Some(crate::drive::CommissioningConfig {
                rated_current_a: values[0],
                rated_voltage_v: values[1],
                bus_v: values[2],
                pole_pitch_m: values[3],
            }),
            COMMISSIONING_QUERY if values == [0.0; 4] => None,
            COMMISSIONING_QUERY => return Err(LinkError::Value),
            _ => return Err(LinkError::Flags),
        };
        Ok(CommissioningRequest { sequence, start })
    }
}

/// Where commissioning stands, as a [`CommissioningReport`] tells it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CommissioningStatus {
    /// None has run since the drive was built (code 0).
    Idle,
    /// Requested or under way (code 1).
    Running,
    /// Finished: the report carries the result (code 2).
    Done,
    /// Stopped with an error, bridge off (code 3).
    Failed,
    /// This start request was refused (e.g. the drive was not disabled); an earlier
    /// commissioning, if any, is untouched (code 4).
    Refused,
}

impl CommissioningStatus {
    /// The status's code on the wire.
    pub const fn code(self) -> u8 {
        match self {
            CommissioningStatus::Idle => 0,
            CommissioningStatus::Running => 1,
            CommissioningStatus::Done => 2,
            CommissioningStatus::Failed => 3,
            CommissioningStatus::Refused => 4,
        }
    }

    /// The status of `code`, `None` for an unknown code.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(CommissioningStatus::Idle),
            1 => Some(CommissioningStatus::Running),
            2 => Some(CommissioningStatus::Done),
            3 => Some(CommissioningStatus::Failed),
            4 => Some(CommissioningStatus::Refused),
            _ => None,
        }
    }

    /// `true` for the statuses that carry an error code (failed, refused).
    pub const fn has_error(self) -> bool {
        matches!(self, CommissioningStatus::Failed | CommissioningStatus::Refused)
    }
}

/// Error codes a [`CommissioningReport`] carries are `1..=COMMISSIONING_ERROR_CODES` (0:
/// none); the drive adapter maps them to and from `CommissioningError`.
pub const COMMISSIONING_ERROR_CODES: u8 = 9;

/// Controller → host, the answer to one [`CommissioningRequest`]: the commissioning's
/// status and, once done, its result (SI, exactly the drive's `f32` values).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommissioningReport {
    /// Sequence number of the request this answers.
    pub sequence: u16,
    /// Where commissioning stands.
    pub status: CommissioningStatus,
    /// With [`CommissioningStatus::Failed`] or [`CommissioningStatus::Refused`]: why,
    /// `1..=`[`COMMISSIONING_ERROR_CODES`] (the drive adapter converts:
    /// `CommissioningReport::error`); else 0.
    pub error_code: u8,
    /// With error code 9 (a fault of the drive's own): its fault bits; else 0.
    pub error_detail: u16,
    /// With [`CommissioningStatus::Done`]: the result; else `None`.
    pub result: Option<crate::drive::CommissioningResult>,
}

/// Points of the voltage-error curve a [`CommissioningReport`] carries.
const CURVE_POINTS: usize = crate::drive::SWEEP_LEVELS;

impl CommissioningReport {
    /// Payload length (bytes).
    pub const PAYLOAD_LEN: usize = 8 + 4 * 8 + 8 * CURVE_POINTS;
    /// Raw length (bytes): payload and CRC.
    pub const RAW_LEN: usize = Self::PAYLOAD_LEN + CRC_LEN;
    /// Length on the wire (bytes).
    pub const WIRE_LEN: usize = wire_len(Self::RAW_LEN);

    fn valid(&self) -> bool {
        let error_ok = if self.status.has_error() {
            (1..=COMMISSIONING_ERROR_CODES).contains(&self.error_code)
        } else {
            self.error_code == 0
        };
        let detail_ok = self.error_code == COMMISSIONING_ERROR_CODES || self.error_detail == 0;
        let result_ok = match (self.status, &self.result) {
            (CommissioningStatus::Done, Some(r)) => {
                result_values(r).iter().all(|x| x.is_finite())
                    && r.curve.iter().all(|p| p.current_a.is_finite() && p.error_v.is_finite())
            }
            (CommissioningStatus::Done, None) => false,
            (_, r) => r.is_none(),
        };
        error_ok && detail_ok && result_ok
    }
}

fn result_values(r: &crate::drive::CommissioningResult) -> [f32; 8] {
    [r.rs_ohm, r.ld_h, r.lq_h, r.psi_f_wb, r.voltage_error_v, r.current_band_a, r.bus_v, r.duration_s]
}

impl Frame for CommissioningReport {
    const PAYLOAD_LEN: usize = CommissioningReport::PAYLOAD_LEN;

    fn write_payload(&self, payload: &mut [u8]) -> Result<(), EncodeError> {
        if !self.valid() {
            return Err(EncodeError::InvalidValue);
        }
        let mut w = Writer::new(payload);
        w.u8(PROTOCOL_VERSION);
        w.u16(self.sequence);
        w.u8(self.status.code());
        w.u8(self.error_code);
        w.u16(self.error_detail);
        match &self.result {
            Some(r) => {
                w.u8(r.direction.to_le_bytes()[0]);
                for x in result_values(r) {
                    w.f32(x);
                }
                for p in &r.curve {
                    w.f32(p.current_a);
                    w.f32(p.error_v);
                }
            }
            None => w.bytes(&[0; Self::PAYLOAD_LEN - 7]),
        }
        w.finish(Self::PAYLOAD_LEN)
    }

    fn read_payload(payload: &[u8]) -> Result<Self, LinkError> {
        let mut r = Reader::new(payload, Self::PAYLOAD_LEN)?;
        r.version()?;
        let sequence = r.u16();
        let status = CommissioningStatus::from_code(r.u8()).ok_or(LinkError::Value)?;
        let error_code = r.u8();
        let error_detail = r.u16();
        let result_bytes = r.bytes::<{ CommissioningReport::PAYLOAD_LEN - 7 }>();
        let result = if status == CommissioningStatus::Done {
            let mut v = Reader::new(&result_bytes, Self::PAYLOAD_LEN - 7)?;
            let direction = i8::from_le_bytes([v.u8()]);
            let mut values = [0.0f32; 8];
            for x in &mut values {
                *x = v.finite_f32()?;
            }
            let mut curve = [crate::drive::VoltageErrorPoint::default(); CURVE_POINTS];
            for p in &mut curve {
                p.current_a = v.finite_f32()?;
                p.error_v = v.finite_f32()?;
            }
            let [rs_ohm, ld_h, lq_h, psi_f_wb, voltage_error_v, current_band_a, bus_v, duration_s] = values;
            Some(crate::drive::CommissioningResult {
                rs_ohm,
                ld_h,
                lq_h,
                psi_f_wb,
                voltage_error_v,
                current_band_a,
                bus_v,
                curve,
                direction,
                duration_s,
            })
        } else if result_bytes.iter().any(|&b| b != 0) {
            return Err(LinkError::Value);
        } else {
            None
        };
        let report = CommissioningReport { sequence, status, error_code, error_detail, result };
        if report.valid() { Ok(report) } else { Err(LinkError::Value) }
    }
}
