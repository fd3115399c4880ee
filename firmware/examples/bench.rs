//! Cost benchmark of the control step, for QEMU `mps2-an386` (Cortex-M4F, `Drive<f32>`)
//! and `mps2-an385` (Cortex-M3, `Drive<Q24>`), run by `host/src/bin/bench_qemu.rs`.
//!
//! # What it runs
//! Every `Drive::step` of a scripted run against the virtual motor (`dcfo::plant`:
//! the motor of the image on the command line, the salient `motors/salient.toml` from
//! `bench_qemu`, with the paper axis's carriage), timed one by one:
//! 1. *speed*: a speed drive (`DriveConfig::for_motor`, DCFO): enable, calibration, the
//!    I/f start-up, the cold acquisition and the hand-over to `Running`; then a lock loss
//!    (`Drive::reset_estimator` at speed) and the re-acquisition back to `Running`.
//! 2. *positioning*: the stroke axis's positioning drive (`DriveConfig::stroke_axis`,
//!    HFI on the salient motor, its inverter compensation for the virtual motor's ideal
//!    bridge): enable, calibration, HFI's alignment, then two moves in
//!    opposite directions, each out of `LowSpeed` into sensorless `Running` and back, the
//!    second one through zero speed at the reversal, and a hold at rest.
//!
//! The run is deterministic: no input but the command line, no interrupt, no clock read
//! that steers anything. Each step's cost is the SysTick count across the call
//! (`timed`), under QEMU's `-icount shift=N`, where every guest instruction advances the
//! virtual clock by `2^N` ns: with SysTick on the 25 MHz core clock (40 ns a tick) and
//! `N = 8`, an instruction is 6.4 ticks, so a count converts to instructions exactly
//! (`bench_qemu` checks the conversion on a sled of `nop`s, and subtracts the `empty`
//! region: the call and the two reads). The virtual motor's period and the bookkeeping
//! between steps are outside the timed region.
//!
//! Per type, the image prints on UART0 (one line each, words separated by spaces):
//! - `CAL <type> <ticks of an empty function> <ticks of the sled> <sled instructions>
//!   <ticks of the empty region>`;
//! - `STAGE <type> <name> <ticks>`: each stage of the step once, on the inputs of the
//!   positioning drive's last step (`clarke`, `cos_sin`, `park`, `pi`, `inverse_park`,
//!   `svpwm`, `dead_time`, `observer`, `pll`);
//! - `STEPS <type> <segment> <state> <count> <sum ticks> <max ticks>`: the steps of a
//!   segment that ended in each drive state (`step` regions);
//! - `ESTIMATOR <type> <segment> <state> <count> <sum ticks> <max ticks>`: the estimator
//!   alone, a copy of the drive's stepped on the drive's own inputs after each step
//!   that had an estimate;
//! - `VISITED <type> <segment> <state>,<state>,..`: the states in the order entered;
//! - `STACK <type> <bytes>`: the deepest stack of one `Drive::step` (painted stack, every
//!   64th step and each step that changes the state), `STACK_HIL <type> <bytes>` the
//!   same for the HIL image's receive path on the byte that completes a frame;
//! - `END <type>`; then the image exits through semihosting `SYS_EXIT` (status 0, or 1
//!   when a drive or the virtual motor could not be built).
//!
//! ```sh
//! cargo run --release -p dcfo-host --bin bench_qemu        # builds and runs it
//! ```
//!
//! On the host this file builds to an empty `main`.
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!("bench is firmware: build it with `--target thumbv7em-none-eabihf` or `thumbv7m-none-eabi`");
}

#[cfg(target_arch = "arm")]
mod firmware {
    use core::fmt::Write as _;
    use core::hint::black_box;

    use cortex_m::peripheral::SYST;
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m_rt::entry;
    use dcfo::algorithms::dead_time::InverterErrorModel;
    use dcfo::algorithms::motion::{Move, ProfileLimits};
    use dcfo::algorithms::observer::{Dcfo, FluxObserver, ObserverInput, ObserverKind, ObserverMotor};
    use dcfo::algorithms::pi::Pi;
    use dcfo::algorithms::pll::Pll;
    use dcfo::algorithms::svpwm::{DcBus, svpwm};
    use dcfo::algorithms::transforms::{Abc, AlphaBeta, CosSin, Dq, clarke, inverse_park, park};
    use dcfo::drive::{
        DeadTimeCompensation, Drive, DriveConfig, DriveState, Measurements, MotionConfig,
        PAPER_AXIS_PAYLOAD_KG, STROKE_AXIS_LIMITS, StepOutput,
    };
    use dcfo::estimator::Estimator;
    use dcfo::link::{SensorFrame, encode};
    use dcfo::motor::MotorParams;
    use dcfo::motor_image::MotorImage;
    #[cfg(not(target_abi = "eabihf"))]
    use dcfo::num::Q24;
    use dcfo::num::units::Base;
    use dcfo::num::{Angle, Scalar};
    use dcfo::plant::{VirtualAxis, VirtualMotor};
    use dcfo_firmware::board::mps2::{CmsdkUart, semihosting_cmdline, semihosting_exit as exit};
    use dcfo_firmware::hil::HilServer;
    use dcfo_firmware::image_drive::motor_image_from_hex;
    use dcfo_firmware::queue::Queue;

    /// Control period of the drives and the virtual motor (s): 10 kHz.
    const TS: f32 = 1e-4;
    /// The speed drive's reference (m/s) and how long it runs (s) before the lock loss
    /// and after it: start-up, acquisition, hand-over and the ramp to the reference fit
    /// in the first, the re-acquisition in the second. The reference lies above the
    /// salient motor's low-speed band (left at 0.41 m/s on the simulated inverter's bus),
    /// where the speed drive runs sensorless; inside it, it would run the low-speed mode.
    const SPEED_M_PER_S: f32 = 0.6;
    const SPEED_RUN_S: f32 = 3.0;
    const REACQUIRE_RUN_S: f32 = 1.0;
    /// The positioning drive: time for calibration and HFI's alignment before the first
    /// move (s), the two moves (m from the start; the second reverses through zero speed
    /// with no dwell between) and the time left for them and a hold at rest (s).
    const ALIGN_S: f32 = 0.3;
    const MOVES: [Move; 2] = [Move { target_m: 0.25, dwell_s: 0.0 }, Move { target_m: 0.02, dwell_s: 0.0 }];
    const MOVE_RUN_S: f32 = 1.5;
    /// The moves' profile: the stroke axis's (`STROKE_AXIS_LIMITS`) but for the top
    /// speed, 0.8 m/s instead of 0.5: the salient motor leaves the low-speed mode only
    /// above 1.25 times its threshold (0.41 m/s on the simulated inverter's bus), so at
    /// 0.5 m/s a move would never run sensorless.
    const LIMITS: ProfileLimits = ProfileLimits { max_speed_m_per_s: 0.8, ..STROKE_AXIS_LIMITS };
    /// Instructions in the calibration sled.
    const SLED: u32 = 64;
    /// Steps between two stack measurements (each paints the stack: about 12,000
    /// instructions, outside the timed regions).
    const STACK_EVERY: u32 = 64;
    /// Stack painted below the probe's frame (bytes) and the paint pattern.
    const PAINT_BYTES: usize = 16 * 1024;
    const PAINT: u32 = 0xA5C3_5A3C;
    /// SysTick's reload: its whole 24-bit range.
    const SYST_MASK: u32 = 0x00FF_FFFF;

    /// A line of output, printed on UART0 (QEMU's semihosting stdout is buffered when
    /// it is a pipe; the serial port is not).
    struct Line {
        buf: [u8; 200],
        len: usize,
    }

    impl Line {
        fn new() -> Self {
            Line { buf: [0; 200], len: 0 }
        }
        fn print(self) {
            // SAFETY: single core, no interrupt handlers: the only UART0 handles are the
            // short-lived ones made here and in `main`, never used at the same time.
            let mut uart = unsafe { CmsdkUart::steal_uart0() };
            let text = self.buf.get(..self.len).unwrap_or_default();
            for &b in text.iter().chain(b"\r\n") {
                uart.write_byte(b);
            }
        }
    }

    impl core::fmt::Write for Line {
        /// Appends what fits; the rest of a too long line is cut off.
        fn write_str(&mut self, s: &str) -> core::fmt::Result {
            for (slot, &b) in self.buf.iter_mut().skip(self.len).zip(s.as_bytes()) {
                *slot = b;
                self.len += 1;
            }
            Ok(())
        }
    }

    macro_rules! println {
        ($($arg:tt)*) => {{
            let mut line = Line::new();
            let _ = write!(line, $($arg)*);
            line.print();
        }};
    }

    /// SysTick counts down (24 bits) on the core clock from here on; no interrupt.
    fn start_clock(syst: &mut SYST) {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(SYST_MASK);
        syst.clear_current();
        syst.disable_interrupt();
        syst.enable_counter();
    }

    /// SysTick ticks spent in `f` (at most 2^24 - 1: 2.6 million instructions at
    /// `shift=8`), and its result, materialised inside the region. Never inlined, so
    /// that the compiler cannot move the caller's instructions in between the reads.
    #[inline(never)]
    fn timed<R>(f: impl FnOnce() -> R) -> (R, u32) {
        let start = SYST::get_current();
        let r = black_box(f());
        let end = SYST::get_current();
        (r, start.wrapping_sub(end) & SYST_MASK)
    }

    // ---- the measured stages: one call each, never inlined into the caller

    #[inline(never)]
    fn stage_empty(x: AlphaBeta<f32>) -> AlphaBeta<f32> {
        x
    }
    /// Nothing: a return.
    #[inline(never)]
    fn stage_nothing() {
        black_box(());
    }
    /// `SLED` instructions more than [`stage_nothing`]: the conversion's check.
    #[inline(never)]
    fn stage_sled() {
        macro_rules! nop8 {
            () => {
                cortex_m::asm::nop();
                cortex_m::asm::nop();
                cortex_m::asm::nop();
                cortex_m::asm::nop();
                cortex_m::asm::nop();
                cortex_m::asm::nop();
                cortex_m::asm::nop();
                cortex_m::asm::nop();
            };
        }
        nop8!();
        nop8!();
        nop8!();
        nop8!();
        nop8!();
        nop8!();
        nop8!();
        nop8!();
    }
    #[inline(never)]
    fn stage_clarke<T: Scalar>(abc: Abc<T>) -> AlphaBeta<T> {
        clarke(abc)
    }
    #[inline(never)]
    fn stage_cos_sin<T: Scalar>(theta: Angle) -> CosSin<T> {
        CosSin::new(theta)
    }
    #[inline(never)]
    fn stage_park<T: Scalar>(ab: AlphaBeta<T>, cs: &CosSin<T>) -> Dq<T> {
        park(ab, cs)
    }
    #[inline(never)]
    fn stage_inverse_park<T: Scalar>(dq: Dq<T>, cs: &CosSin<T>) -> AlphaBeta<T> {
        inverse_park(dq, cs)
    }
    #[inline(never)]
    fn stage_pi<T: Scalar>(pi: &mut Pi<T>, error: T, lo: T, hi: T) -> T {
        pi.update_within(error, lo, hi)
    }
    #[inline(never)]
    fn stage_svpwm<T: Scalar>(u: AlphaBeta<T>, vdc: T) -> bool {
        svpwm(u, vdc).map(|m| black_box(m).limited).unwrap_or(true)
    }
    #[inline(never)]
    fn stage_dead_time<T: Scalar>(
        model: &InverterErrorModel<T>,
        u: AlphaBeta<T>,
        bus: &DcBus<T>,
        i: Abc<T>,
    ) -> AlphaBeta<T> {
        model.compensation(u, bus, i)
    }
    #[inline(never)]
    fn stage_observer<T: Scalar>(obs: &mut Dcfo<T>, input: &ObserverInput<T>) -> Option<AlphaBeta<T>> {
        obs.update(input).ok().map(|f| f.psi_ab)
    }
    #[inline(never)]
    fn stage_pll<T: Scalar>(pll: &mut Pll<T>, psi: AlphaBeta<T>, dt: T) -> Option<Angle> {
        pll.update(psi, dt).ok().map(|o| o.theta_e)
    }
    #[inline(never)]
    fn stage_estimator<T: Scalar>(
        est: &mut Estimator<T>,
        u: AlphaBeta<T>,
        i: AlphaBeta<T>,
        dt: T,
    ) -> Option<Angle> {
        est.update(u, i, dt).ok().map(|e| e.theta_e)
    }
    #[inline(never)]
    fn stage_step<T: Scalar>(drive: &mut Drive<T>, m: &Measurements<T>) -> StepOutput<T> {
        drive.step(m)
    }

    /// One control step, returning what the run needs of its output (the duties, the
    /// bridge flag, the state, the estimator's inputs) in registers: a firmware uses the
    /// output in place, and copying the whole output out of the timed call would be the
    /// bench's cost, not the drive's.
    #[inline(never)]
    fn stage_step_brief<T: Scalar>(drive: &mut Drive<T>, m: &Measurements<T>) -> Brief<T> {
        let out = drive.step(m);
        Brief {
            duties: [out.duties.a, out.duties.b, out.duties.c],
            bridge: out.bridge_enabled,
            state: out.state,
            estimate: out.estimate.is_some(),
            u_applied: out.u_applied,
            i_observer: out.i_observer,
        }
    }

    /// What the run keeps of a step's output.
    #[derive(Clone, Copy)]
    struct Brief<T> {
        duties: [T; 3],
        bridge: bool,
        state: DriveState,
        estimate: bool,
        u_applied: AlphaBeta<T>,
        i_observer: AlphaBeta<T>,
    }

    /// Deepest stack (bytes below the caller's stack pointer) used by `f`.
    #[inline(never)]
    fn stack_depth(f: impl FnOnce()) -> usize {
        let sp = cortex_m::register::msp::read() as usize;
        // Leave 64 bytes under the stack pointer for this function's own calls.
        let top = (sp - 64) & !3;
        let bottom = top - PAINT_BYTES;
        for a in (bottom..top).step_by(4) {
            // SAFETY: the painted words lie below the stack pointer in the 4 MiB RAM
            // (the stack starts at its top), in memory no live frame uses.
            unsafe { core::ptr::write_volatile(a as *mut u32, PAINT) };
        }
        f();
        let mut low = top;
        for a in (bottom..top).step_by(4) {
            // SAFETY: as above; reading back the painted words.
            if unsafe { core::ptr::read_volatile(a as *const u32) } != PAINT {
                low = a;
                break;
            }
        }
        sp - low
    }

    /// Deepest stack of the HIL image's receive path on the byte that completes a frame:
    /// `HilServer::on_byte` (decode, `Drive::step`, encode, queue), as `qemu_hil`'s UART
    /// interrupt runs it.
    fn hil_stack_depth<T: Scalar>(drive: &Drive<T>, vdc_v: f32) -> usize {
        let mut server = HilServer::new(drive.clone());
        let mut queue: Queue<u8, 128> = Queue::new();
        let (mut tx, _rx) = queue.split();
        let frame = SensorFrame {
            sequence: 0,
            i_a: 0.1,
            i_b: -0.05,
            i_c: -0.05,
            vdc: vdc_v,
            speed_ref: SPEED_M_PER_S,
            enable: true,
            clear_faults: false,
            move_to: None,
        };
        let mut wire = [0u8; SensorFrame::WIRE_LEN];
        let Ok(n) = encode(&frame, &mut wire) else { return 0 };
        let Some((&last, head)) = wire.get(..n).and_then(|w| w.split_last()) else { return 0 };
        for &b in head {
            server.on_byte(b, &mut tx);
        }
        stack_depth(|| server.on_byte(black_box(last), &mut tx))
    }

    /// A state's index in the tallies: its telemetry code (`DriveState::ALL` order).
    fn state_index(s: DriveState) -> usize {
        usize::from(s.code())
    }

    fn state_name(s: DriveState) -> &'static str {
        match s {
            DriveState::Disabled => "disabled",
            DriveState::Calibrating => "calibrating",
            DriveState::Starting => "starting",
            DriveState::Running => "running",
            DriveState::Fault => "fault",
            DriveState::Reacquiring => "reacquiring",
            DriveState::LowSpeed => "low_speed",
            DriveState::Commissioning => "commissioning",
        }
    }

    /// Count, sum and maximum of a region's ticks.
    #[derive(Clone, Copy, Default)]
    struct Tally {
        count: u32,
        sum: u64,
        max: u32,
    }

    impl Tally {
        fn add(&mut self, ticks: u32) {
            self.count += 1;
            self.sum += u64::from(ticks);
            self.max = self.max.max(ticks);
        }
    }

    /// The states a segment entered, in order (each change once; at most 16 kept).
    struct Visits {
        states: [DriveState; 16],
        len: usize,
    }

    impl Visits {
        fn new() -> Self {
            Visits { states: [DriveState::Disabled; 16], len: 0 }
        }
        fn enter(&mut self, s: DriveState) {
            let changed = self.len == 0 || self.states.get(self.len - 1) != Some(&s);
            if let Some(slot) = self.states.get_mut(self.len).filter(|_| changed) {
                *slot = s;
                self.len += 1;
            }
        }
    }

    /// One drive on the virtual motor, with the tallies of its steps by state.
    struct Segment<'a, T> {
        ty: &'static str,
        name: &'static str,
        drive: Drive<T>,
        plant: VirtualMotor,
        base: Base,
        /// The last step's output (the plant applies it during the period after the next).
        last: Brief<T>,
        /// `u_applied` of the step before the last: the estimator's voltage input.
        u_prev: AlphaBeta<T>,
        dt: T,
        steps: [Tally; 8],
        estimator: [Tally; 8],
        visits: Visits,
        stack: &'a mut usize,
        count: u32,
    }

    impl<'a, T: Scalar> Segment<'a, T> {
        fn new(
            ty: &'static str,
            name: &'static str,
            drive: Drive<T>,
            plant: VirtualMotor,
            base: Base,
            stack: &'a mut usize,
        ) -> Self {
            let zero = AlphaBeta::default();
            Segment {
                ty,
                name,
                drive,
                plant,
                base,
                last: Brief {
                    duties: [T::HALF; 3],
                    bridge: false,
                    state: DriveState::Disabled,
                    estimate: false,
                    u_applied: zero,
                    i_observer: zero,
                },
                u_prev: zero,
                dt: base.time(TS),
                steps: [Tally::default(); 8],
                estimator: [Tally::default(); 8],
                visits: Visits::new(),
                stack,
                count: 0,
            }
        }

        /// The virtual motor's currents and bus as the drive's measurements.
        fn measure(&self) -> Measurements<T> {
            Measurements::from_si(self.plant.phase_currents_a(), self.plant.bus_v(), &self.base)
        }

        /// `seconds` of control periods: one timed step on the plant's currents, the
        /// estimator's copy stepped and timed after it, then the plant over one period
        /// with the step before's output.
        fn run(&mut self, seconds: f32) {
            let n = (seconds / TS) as u32;
            for _ in 0..n {
                let m = self.measure();
                let estimator = self.drive.estimator().clone();
                let before = self.last.state;
                let measure_stack = self.count.is_multiple_of(STACK_EVERY);
                let (out, ticks) = if measure_stack {
                    let mut result = None;
                    let depth =
                        stack_depth(|| result = Some(timed(|| stage_step_brief(&mut self.drive, &m))));
                    *self.stack = (*self.stack).max(depth);
                    match result {
                        Some(r) => r,
                        None => return,
                    }
                } else {
                    timed(|| stage_step_brief(black_box(&mut self.drive), black_box(&m)))
                };
                if let Some(t) = self.steps.get_mut(state_index(out.state)) {
                    t.add(ticks);
                }
                self.visits.enter(out.state);
                if out.state != before && !measure_stack {
                    // A change of state: its step once more on a painted stack, on a copy.
                    let mut copy = self.drive.clone();
                    let depth = stack_depth(|| {
                        black_box(stage_step(&mut copy, black_box(&m)));
                    });
                    *self.stack = (*self.stack).max(depth);
                }
                if out.estimate {
                    let mut copy = estimator;
                    let (_, ticks) = timed(|| {
                        stage_estimator(
                            black_box(&mut copy),
                            black_box(self.u_prev),
                            black_box(out.i_observer),
                            self.dt,
                        )
                    });
                    if let Some(t) = self.estimator.get_mut(state_index(out.state)) {
                        t.add(ticks);
                    }
                }
                // The plant applies the previous step's output over the next period: a
                // board's preloaded PWM registers (one period of computation delay).
                let d = self.last.duties.map(|x| x.to_f32());
                self.plant.step(d, self.last.bridge);
                self.u_prev = out.u_applied;
                self.last = out;
                self.count += 1;
            }
        }

        fn report(&self) {
            let (ty, name) = (self.ty, self.name);
            for (k, s) in DriveState::ALL.iter().enumerate() {
                if let Some(t) = self.steps.get(k).filter(|t| t.count > 0) {
                    println!("STEPS {ty} {name} {} {} {} {}", state_name(*s), t.count, t.sum, t.max);
                }
                if let Some(t) = self.estimator.get(k).filter(|t| t.count > 0) {
                    println!("ESTIMATOR {ty} {name} {} {} {} {}", state_name(*s), t.count, t.sum, t.max);
                }
            }
            let mut line = Line::new();
            let _ = write!(line, "VISITED {ty} {name} ");
            for (k, s) in self.visits.states.iter().take(self.visits.len).enumerate() {
                let _ = write!(line, "{}{}", if k == 0 { "" } else { "," }, state_name(*s));
            }
            line.print();
        }
    }

    /// The virtual motor of `image` on the paper axis's carriage, at rest.
    fn plant_for(image: &MotorImage) -> Option<VirtualMotor> {
        let axis =
            VirtualAxis { payload_kg: PAPER_AXIS_PAYLOAD_KG, load_n: 0.0, bus_v: image.bus_v, period_s: TS };
        VirtualMotor::new(&image.motor, &axis).ok()
    }

    /// The whole run for number type `T` in `base`: the two segments, then the stages.
    fn bench<T: Scalar>(ty: &'static str, image: &MotorImage, base: Base) -> Option<()> {
        let motor = image.motor;
        // Calibration of the conversion (a function of nothing, the sled), and the
        // empty region (a call with an argument and a result) subtracted from the others.
        let (_, nothing) = timed(stage_nothing);
        let (_, sled) = timed(stage_sled);
        let (_, empty) = timed(|| stage_empty(black_box(AlphaBeta::new(1.0, 2.0))));
        println!("CAL {ty} {nothing} {sled} {SLED} {empty}");
        let mut stack = 0usize;

        // 1. The speed drive: start-up, acquisition, a lock loss and the re-acquisition.
        let mut config = DriveConfig::for_motor(&motor, image.bus_v, ObserverKind::Dcfo);
        config.moving_mass_kg = motor.mass_kg + PAPER_AXIS_PAYLOAD_KG;
        config.control_period_s = TS;
        let drive = Drive::<T>::new(&motor, &config, &base).ok()?;
        let mut speed = Segment::new(ty, "speed", drive, plant_for(image)?, base, &mut stack);
        speed.drive.set_speed_reference(speed.drive.omega_from_speed(SPEED_M_PER_S));
        speed.drive.enable();
        speed.run(SPEED_RUN_S);
        speed.drive.reset_estimator();
        speed.run(REACQUIRE_RUN_S);
        speed.report();
        drop(speed);

        // 2. The positioning drive with HFI: alignment, a move out and one back through
        //    zero speed, a hold.
        let mut config = DriveConfig::stroke_axis(&motor, image.bus_v);
        // The virtual motor's bridge is ideal: the compensation runs, at its whole cost
        // (with no dead time its edge ripple is formed at every duty spread), for a bridge
        // with no dead time and no drop. Compensating the stroke axis's 6.6 V an ideal
        // bridge does not lose ran the mover 23 mm past its target at the reversal.
        if let Some(c) = &mut config.dead_time_compensation {
            c.dead_time_s = 0.0;
            c.device_drop_v = 0.0;
        }
        config.check_profile(&motor, &LIMITS).ok()?;
        config.motion = Some(MotionConfig::for_drive(&motor, &config, LIMITS));
        let drive = Drive::<T>::new(&motor, &config, &base).ok()?;
        let mut pos = Segment::new(ty, "positioning", drive, plant_for(image)?, base, &mut stack);
        pos.drive.enable();
        pos.run(ALIGN_S);
        for m in MOVES {
            pos.drive.push_move(m).ok()?;
        }
        pos.run(MOVE_RUN_S);
        pos.report();

        // The stages, once each on the last step's inputs.
        stages(&mut pos, &config, &motor);
        let hil = hil_stack_depth(&pos.drive, image.bus_v);
        drop(pos);
        println!("STACK {ty} {stack}");
        println!("STACK_HIL {ty} {hil}");
        println!("END {ty}");
        Some(())
    }

    /// Each stage of the step once, on the inputs of `seg`'s last step; the observer and
    /// the PLL as fresh ones fed the same inputs over 200 steps first.
    fn stages<T: Scalar>(seg: &mut Segment<'_, T>, config: &DriveConfig, motor: &MotorParams) {
        let ty = seg.ty;
        let base = seg.base;
        let m = seg.measure();
        let out = stage_step(&mut seg.drive, &m);
        let theta = out.theta_control;
        let cs: CosSin<T> = CosSin::new(theta);
        let v_max = m.vdc * T::from_f32(0.95 * 0.577_350_26);
        let Ok(mut pi) = Pi::new(T::from_f32(0.1), T::from_f32(0.01), -v_max, v_max) else { return };
        let err = out.i_dq_ref.q - out.i_dq.q;
        let u_dq = Dq::new(base.voltage(5.0), base.voltage(30.0));
        let u_ab = inverse_park(u_dq, &cs);
        let compensation = config.dead_time_compensation.unwrap_or(DeadTimeCompensation {
            dead_time_s: 2e-6,
            device_drop_v: 0.95,
            current_band_a: 0.01,
        });
        let model = InverterErrorModel::<T>::for_drive(&compensation, TS, motor, &base);
        let Ok(mut observer) =
            Dcfo::<T>::new(ObserverMotor::new(motor, &base), &config.estimator.dcfo, &base)
        else {
            return;
        };
        let Ok(mut pll) = Pll::<T>::new(&config.estimator.pll, motor.pole_pitch_m, &base) else { return };
        let dt = seg.dt;
        let mut input = ObserverInput { u_ab: out.u_applied, i_ab: out.i_observer, omega_e: T::ZERO, dt };
        for _ in 0..200 {
            seg.run(TS);
            input = ObserverInput {
                u_ab: seg.u_prev,
                i_ab: seg.last.i_observer,
                omega_e: pll.omega_integral(),
                dt,
            };
            if let Ok(flux) = observer.update(&input) {
                let _ = pll.update(flux.psi_ab, dt);
            }
        }
        let psi = observer.clone().update(&input).map(|f| f.psi_ab).unwrap_or_default();
        let i_abc = m.i_abc;
        let stage = |name: &str, ticks: u32| println!("STAGE {ty} {name} {ticks}");
        let Ok(bus) = DcBus::new(m.vdc) else { return };
        stage("clarke", timed(|| stage_clarke(black_box(i_abc))).1);
        stage("cos_sin", timed(|| stage_cos_sin::<T>(black_box(theta))).1);
        stage("park", timed(|| stage_park(black_box(out.i_ab), black_box(&cs))).1);
        stage(
            "pi",
            timed(|| stage_pi(black_box(&mut pi), black_box(err), black_box(-v_max), black_box(v_max))).1,
        );
        stage("inverse_park", timed(|| stage_inverse_park(black_box(u_dq), black_box(&cs))).1);
        stage("svpwm", timed(|| stage_svpwm(black_box(u_ab), black_box(m.vdc))).1);
        stage(
            "dead_time",
            timed(|| stage_dead_time(black_box(&model), black_box(u_ab), black_box(&bus), black_box(i_abc)))
                .1,
        );
        stage("observer", timed(|| stage_observer(black_box(&mut observer), black_box(&input))).1);
        stage("pll", timed(|| stage_pll(black_box(&mut pll), black_box(psi), black_box(dt))).1);
    }

    /// The motor image from the command line (`image <hex>`, QEMU's `-append`).
    fn image_from_cmdline() -> Option<MotorImage> {
        let mut line = [0u8; 512];
        let line = semihosting_cmdline(&mut line)?;
        let mut words = line.split(|&b| b == b' ').filter(|w| !w.is_empty());
        words.by_ref().find(|w| *w == b"image")?;
        motor_image_from_hex(words.next()?).ok()
    }

    #[entry]
    fn main() -> ! {
        // SAFETY: the first UART0 handle; see `Line::print`.
        let mut uart = unsafe { CmsdkUart::steal_uart0() };
        uart.init(115_200);
        let Some(mut cp) = cortex_m::Peripherals::take() else { exit(false) };
        start_clock(&mut cp.SYST);
        let Some(image) = image_from_cmdline() else {
            println!("ERROR no motor image on the command line (`image <hex>`)");
            exit(false)
        };
        #[cfg(target_abi = "eabihf")]
        let ok = bench::<f32>("f32", &image, Base::SI).is_some();
        #[cfg(not(target_abi = "eabihf"))]
        let ok = bench::<Q24>("q24", &image, Base::for_motor(&image.motor)).is_some();
        if !ok {
            println!("ERROR a drive or the virtual motor could not be built, or a move was refused");
        }
        exit(ok)
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        println!("PANIC {info}");
        exit(false)
    }
}
