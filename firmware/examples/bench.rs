//! Instruction-count benchmark of the control step, for QEMU `mps2-an386` (Cortex-M4F,
//! f32 and Q24) and `mps2-an385` (Cortex-M3, Q24).
//!
//! The firmware brings a drive into its sensorless `Running` state against a small
//! built-in plant (the paper motor, its mover held at the hand-over speed of 0.25 m/s,
//! an ideal inverter), then calls each stage of the control step once, on the inputs of
//! the drive's last step, between calls of the marker functions `bench_begin` and
//! `bench_end`. Run under `qemu-system-arm -singlestep -d exec,nochain`, every executed
//! instruction is one trace line; the host program `host/src/bin/bench_qemu.rs` counts
//! the lines from an entry of `bench_begin` to the next entry of `bench_end` and
//! subtracts the count of the `empty` region (an empty stage: markers and call overhead).
//!
//! UART0 gets, per numeric type, `STATE <type> <state> <steps>` after the warm-up,
//! then `READY`; the firmware then waits for one byte on UART0 (the host switches the
//! exec log on first, so the warm-up is not traced). Then, per type, a line
//! `BENCH <type> <region>,<region>,..` naming the regions that follow, in order,
//! `END <type> <state>`, `STACK <type> <bytes>` (the deepest stack used by one
//! `Drive::step`, from a painted stack) and `STACK_HIL <type> <bytes>` (the same for the
//! HIL image's receive path on the byte that completes a frame). The firmware exits through semihosting
//! `SYS_EXIT` (status 0, or 1 when a drive could not be built).
//!
//! ```sh
//! cargo build -p dcfo-firmware --release --features mps2 --target thumbv7em-none-eabihf --example bench
//! echo g | qemu-system-arm -M mps2-an386 -cpu cortex-m4 -display none -monitor none \
//!     -semihosting-config enable=on,target=native -serial stdio \
//!     -kernel target/thumbv7em-none-eabihf/release/examples/bench
//! cargo build -p dcfo-firmware --release --features mps2 --target thumbv7m-none-eabi --example bench
//! echo g | qemu-system-arm -M mps2-an385 -cpu cortex-m3 ... \
//!     -kernel target/thumbv7m-none-eabi/release/examples/bench
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
    use core::sync::atomic::AtomicU32;

    use cortex_m as _; // critical-section implementation (single core)
    use cortex_m_rt::entry;
    use dcfo::drive::{Drive, DriveConfig, DriveState, Measurements, StepOutput};
    use dcfo::estimator::Estimator;
    use dcfo::link::{SensorFrame, encode};
    use dcfo::motor::MotorParams;
    use dcfo::num::{Angle, Q24, Scalar};
    use dcfo::observer::{Dcfo, FluxObserver, ObserverInput, ObserverKind, ObserverMotor};
    use dcfo::pi::Pi;
    use dcfo::pll::Pll;
    use dcfo::svpwm::svpwm;
    use dcfo::transforms::{Abc, AlphaBeta, CosSin, Dq, clarke, inverse_clarke, inverse_park, park};
    use dcfo::units::Base;
    use dcfo_firmware::board::mps2::{CmsdkUart, semihosting_exit as exit};
    use dcfo_firmware::hil::HilServer;
    use dcfo_firmware::queue::Queue;

    /// Control period of the drive and the plant (s).
    const TS: f32 = 1e-4;
    /// Mover speed (m/s): the start-up's hand-over speed, so the drive hands over.
    const SPEED_M_PER_S: f32 = 0.25;
    /// Steps after which the bench gives up waiting for `Running` (2 s).
    const MAX_WARMUP_STEPS: u32 = 20_000;
    /// Steps run in `Running` before measuring (the hand-over's d-axis ramp is 50 ms).
    const RUNNING_STEPS: u32 = 600;
    /// Consecutive control steps measured (one speed-loop period).
    const MEASURED_STEPS: usize = 10;
    /// Estimator steps measured from a re-acquisition on (80 ms): at the plant's 8.3 Hz
    /// the circle fit ends within them (`ACQUIRE` reports the step), so they include
    /// every sample the back-EMF fit solves and the seed.
    const ACQUIRE_STEPS: usize = 800;
    /// Stack painted below the probe's frame (bytes) and the paint pattern.
    const PAINT_BYTES: usize = 16 * 1024;
    const PAINT: u32 = 0xA5C3_5A3C;

    /// Written by the markers (distinct values: the two bodies differ and are never merged).
    static MARK: AtomicU32 = AtomicU32::new(0);

    /// Marks the start of a measured region: the host counts trace lines from an entry
    /// of this function to the next entry of [`bench_end`].
    #[unsafe(no_mangle)]
    #[inline(never)]
    pub extern "C" fn bench_begin() {
        // SAFETY: a valid, aligned static; volatile, so the call is never optimised out.
        unsafe { MARK.as_ptr().write_volatile(1) };
    }

    /// Marks the end of a measured region.
    #[unsafe(no_mangle)]
    #[inline(never)]
    pub extern "C" fn bench_end() {
        // SAFETY: a valid, aligned static; volatile, so the call is never optimised out.
        unsafe { MARK.as_ptr().write_volatile(2) };
    }

    /// A line of output, printed on UART0 (QEMU's semihosting stdout is buffered when
    /// it is a pipe; the serial port is not).
    struct Line {
        buf: [u8; 256],
        len: usize,
    }

    impl Line {
        fn new() -> Self {
            Line { buf: [0; 256], len: 0 }
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

    // ---- the plant: paper motor, mover at constant speed, ideal inverter (SI, f32)

    struct Plant {
        i_ab: AlphaBeta<f32>,
        theta: Angle,
        d_theta: Angle,
        psi_f: f32,
        rs: f32,
        ls: f32,
    }

    impl Plant {
        fn new(motor: &MotorParams) -> Self {
            let omega = motor.omega_e_from_speed(SPEED_M_PER_S);
            Plant {
                i_ab: AlphaBeta::default(),
                theta: Angle::ZERO,
                d_theta: (omega * TS).radians_to_angle(),
                psi_f: motor.psi_f_wb,
                rs: motor.rs_ohm,
                ls: motor.lq_h,
            }
        }

        fn flux(&self, theta: Angle) -> AlphaBeta<f32> {
            let (c, s) = f32::cos_sin(theta);
            AlphaBeta::new(self.psi_f * c, self.psi_f * s)
        }

        /// One period with `u` (V) applied, `Ls di = (u - Rs i) dt - d psi`, or with
        /// the bridge off (`None`: no current; the back-EMF stays below the bus).
        fn advance(&mut self, u: Option<AlphaBeta<f32>>) {
            let next = self.theta + self.d_theta;
            let Some(u) = u else {
                self.i_ab = AlphaBeta::default();
                self.theta = next;
                return;
            };
            let (p0, p1) = (self.flux(self.theta), self.flux(next));
            let k = 1.0 / self.ls;
            self.i_ab.alpha += k * ((u.alpha - self.rs * self.i_ab.alpha) * TS - (p1.alpha - p0.alpha));
            self.i_ab.beta += k * ((u.beta - self.rs * self.i_ab.beta) * TS - (p1.beta - p0.beta));
            self.theta = next;
        }
    }

    // ---- the measured stages: one call each, never inlined into the caller

    #[inline(never)]
    fn stage_empty(x: AlphaBeta<f32>) -> AlphaBeta<f32> {
        x
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

    /// One control step, keeping what the bench's plant needs (the applied voltage,
    /// the bridge flag, the state). Storing the whole 104-byte output into a field made
    /// the caller copy it inside the measured region (111 instructions of `memcpy`),
    /// which is the bench's cost, not the drive's; a firmware uses the output in place.
    #[inline(never)]
    fn stage_step_brief<T: Scalar>(
        drive: &mut Drive<T>,
        m: &Measurements<T>,
    ) -> (AlphaBeta<T>, bool, DriveState) {
        let out = drive.step(m);
        (out.u_applied, out.bridge_enabled, out.state)
    }

    /// Runs `f` between the markers; its result is materialised inside the region.
    macro_rules! region {
        ($f:expr) => {{
            bench_begin();
            black_box($f);
            bench_end();
        }};
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

    fn state_name(s: DriveState) -> &'static str {
        match s {
            DriveState::Disabled => "disabled",
            DriveState::Calibrating => "calibrating",
            DriveState::Starting => "starting",
            DriveState::Running => "running",
            DriveState::Fault => "fault",
            DriveState::Reacquiring => "reacquiring",
            DriveState::LowSpeed => "low speed",
            DriveState::Commissioning => "commissioning",
        }
    }

    /// A drive warmed up on the plant, with replicas of its estimator (fed the drive's
    /// own observer inputs) and the inputs of its last step.
    struct Bench<T> {
        name: &'static str,
        base: Base,
        drive: Drive<T>,
        estimator: Estimator<T>,
        observer: Dcfo<T>,
        pll: Pll<T>,
        plant: Plant,
        out: StepOutput<T>,
        /// The estimator's voltage input of the next step: this step's `u_applied`.
        u_observer: AlphaBeta<T>,
        last_input: ObserverInput<T>,
        dt: T,
        vdc: T,
    }

    impl<T: Scalar> Bench<T> {
        /// Brings a drive into `Running` (or gives up after `MAX_WARMUP_STEPS`).
        fn warm_up(name: &'static str, base: Base) -> Option<Self> {
            let motor = MotorParams::paper();
            let mut config = DriveConfig::paper_axis(ObserverKind::Dcfo);
            // A shorter start-up than the axis's (same sequence): less to simulate.
            config.faults.calibration_samples = 16;
            config.startup.accel_m_per_s2 = 25.0;
            config.startup.dwell_s = 0.1;
            let drive = Drive::<T>::new(&motor, &config, &base).ok()?;
            let estimator = Estimator::<T>::new(&motor, &config.estimator, &base).ok()?;
            let observer =
                Dcfo::<T>::new(ObserverMotor::new(&motor, &base), &config.estimator.dcfo, &base).ok()?;
            let pll = Pll::<T>::new(&config.estimator.pll, motor.pole_pitch_m, &base).ok()?;
            let dt: T = base.time(TS);
            let vdc: T = base.voltage(dcfo::drive::PAPER_AXIS_BUS_V);
            let plant = Plant::new(&motor);
            let out = StepOutput {
                duties: Default::default(),
                bridge_enabled: false,
                state: DriveState::Disabled,
                faults: Default::default(),
                estimate: None,
                theta_control: Angle::ZERO,
                i_ab: AlphaBeta::default(),
                i_dq: Dq::default(),
                i_dq_ref: Dq::default(),
                u_applied: AlphaBeta::default(),
                i_observer: AlphaBeta::default(),
                alpha_e_ref: T::ZERO,
            };
            let mut b = Bench {
                name,
                base,
                drive,
                estimator,
                observer,
                pll,
                plant,
                out,
                u_observer: AlphaBeta::default(),
                last_input: ObserverInput::default(),
                dt,
                vdc,
            };
            b.drive.set_speed_reference(b.drive.omega_from_speed(SPEED_M_PER_S));
            b.drive.enable();
            b.out = b.drive.step(&b.measure());
            let mut steps = 1u32;
            let mut running = 0u32;
            while running < RUNNING_STEPS && steps < MAX_WARMUP_STEPS {
                if b.out.estimate.is_some() {
                    let (u, i) = (b.u_observer, b.out.i_observer);
                    let _ = b.estimator.update(u, i, dt);
                    b.last_input = ObserverInput { u_ab: u, i_ab: i, omega_e: b.pll.omega_integral(), dt };
                    if let Ok(flux) = b.observer.update(&b.last_input) {
                        let _ = b.pll.update(flux.psi_ab, dt);
                    }
                }
                b.u_observer = b.out.u_applied;
                let prev = b.out.state;
                b.advance();
                b.out = b.drive.step(&b.measure());
                steps += 1;
                if b.out.state != prev {
                    println!(
                        "TRANSITION {name} step {steps} {} faults {:#x}",
                        state_name(b.out.state),
                        b.out.faults.bits()
                    );
                }
                if b.out.state == DriveState::Running {
                    running += 1;
                }
            }
            println!("STATE {name} {} {steps}", state_name(b.out.state));
            Some(b)
        }

        /// The plant's currents as the drive's measurements.
        fn measure(&self) -> Measurements<T> {
            let i = inverse_clarke(self.plant.i_ab);
            let b = &self.base;
            Measurements {
                i_abc: Abc { a: b.current(i.a), b: b.current(i.b), c: b.current(i.c) },
                vdc: self.vdc,
            }
        }

        /// The plant over one period with the last step's output.
        fn advance(&mut self) {
            let u = self.out.u_applied;
            let b = &self.base;
            let u = self.out.bridge_enabled.then(|| AlphaBeta::new(b.to_volts(u.alpha), b.to_volts(u.beta)));
            self.plant.advance(u);
        }

        /// Each stage once, then `MEASURED_STEPS` control steps, each between the markers.
        fn measure_stages(&mut self) {
            let name = self.name;
            let out = self.out;
            let m = self.measure();
            let theta = out.theta_control;
            let cs: CosSin<T> = CosSin::new(theta);
            let v_max = self.vdc * T::from_f32(0.95 * 0.577_350_26);
            let Ok(mut pi) = Pi::new(T::from_f32(0.1), T::from_f32(0.01), -v_max, v_max) else {
                return;
            };
            let err = out.i_dq_ref.q - out.i_dq.q;
            let u_dq = Dq::new(self.base.voltage(5.0), self.base.voltage(30.0));
            let u_ab = inverse_park(u_dq, &cs);
            let psi = self.observer.update(&self.last_input).map(|f| f.psi_ab).unwrap_or_default();
            let dt = self.dt;

            let mut line = Line::new();
            let _ = write!(
                line,
                "BENCH {name} empty,clarke,cos_sin,park,pi,inverse_park,svpwm,observer,pll,estimator"
            );
            let _ = write!(line, ",step*{MEASURED_STEPS},acquire*{ACQUIRE_STEPS}");
            line.print();
            region!(stage_empty(black_box(AlphaBeta::new(1.0, 2.0))));
            region!(stage_clarke(black_box(m.i_abc)));
            region!(stage_cos_sin::<T>(black_box(theta)));
            region!(stage_park(black_box(out.i_ab), black_box(&cs)));
            region!(stage_pi(black_box(&mut pi), black_box(err), black_box(-v_max), black_box(v_max)));
            region!(stage_inverse_park(black_box(u_dq), black_box(&cs)));
            region!(stage_svpwm(black_box(u_ab), black_box(self.vdc)));
            region!(stage_observer(black_box(&mut self.observer), black_box(&self.last_input)));
            region!(stage_pll(black_box(&mut self.pll), black_box(psi), black_box(dt)));
            region!(stage_estimator(
                black_box(&mut self.estimator),
                black_box(self.u_observer),
                black_box(out.i_observer),
                dt
            ));
            for _ in 0..MEASURED_STEPS {
                self.advance();
                let m = self.measure();
                bench_begin();
                let (u_applied, bridge_enabled, state) =
                    stage_step_brief(black_box(&mut self.drive), black_box(&m));
                bench_end();
                (self.out.u_applied, self.out.bridge_enabled, self.out.state) =
                    (u_applied, bridge_enabled, state);
            }
            // The estimator from a re-acquisition (a lock loss at speed), fed the running
            // drive's own observer inputs: every step until and past the circle fit's end.
            let mut acquiring = self.estimator.clone();
            acquiring.reacquire();
            let mut fit_end = None;
            for k in 0..ACQUIRE_STEPS {
                let (u, i) = (self.out.u_applied, self.out.i_observer);
                region!(stage_estimator(black_box(&mut acquiring), black_box(u), black_box(i), dt));
                if fit_end.is_none() && !acquiring.fitting() {
                    fit_end = Some(k);
                }
                self.advance();
                let m = self.measure();
                self.out = self.drive.step(&m);
            }
            match fit_end {
                Some(k) => println!("ACQUIRE {name} {k}"),
                None => println!("ACQUIRE {name} none"),
            }
            println!("END {name} {}", state_name(self.out.state));
            self.advance();
            let m = self.measure();
            let depth = stack_depth(|| {
                black_box(stage_step(&mut self.drive, black_box(&m)));
            });
            println!("STACK {name} {depth}");
            println!("STACK_HIL {name} {}", hil_stack_depth(&self.drive, dcfo::drive::PAPER_AXIS_BUS_V));
        }
    }

    #[entry]
    fn main() -> ! {
        let motor = MotorParams::paper();
        // SAFETY: the first UART0 handle; see `Line::print`.
        let mut uart = unsafe { CmsdkUart::steal_uart0() };
        uart.init(115_200);
        #[cfg(target_abi = "eabihf")]
        let mut f = Bench::<f32>::warm_up("f32", Base::SI);
        let mut q = Bench::<Q24>::warm_up("q24", Base::for_motor(&motor));

        // The gate: the host switches QEMU's exec log on, then sends a byte on UART0.
        uart.enable_rx_wakeup();
        println!("READY");
        let _ = uart.read_byte();

        let mut ok = true;
        #[cfg(target_abi = "eabihf")]
        match f.as_mut() {
            Some(b) => b.measure_stages(),
            None => ok = false,
        }
        match q.as_mut() {
            Some(b) => b.measure_stages(),
            None => ok = false,
        }
        exit(ok)
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        println!("PANIC {info}");
        exit(false)
    }
}
