//! What every drive image on a Cortex-M does the same way, whatever its board, so that an
//! image (`examples/`) says only what is its own: its board, its drive, its interrupts'
//! priorities and rates.
//!
//! - [`Slot`], [`slot`], [`install`], [`with_slot`]: the state an interrupt owns, put in place once
//!   by `main` and borrowed only inside critical sections (never nested), so a borrow
//!   cannot fail; were it to, the caller is told and nothing panics.
//! - [`DriveOnBoard`] and [`BoardLinkState`]: the drive image's control period (one
//!   [`ControlLoop::period`] on the board, then the capture and the status) and the
//!   thread's side of the board link (a received byte in, the encoded answer out).
//! - [`StallCheck`]: a control interrupt that stops coming is seen by a slower periodic
//!   interrupt, which switches the bridge off (a drive on a real power stage needs it:
//!   the PWM timer would go on switching at the last duties with nothing in control).
//! - [`start_systick`]: SysTick at a priority and a reload, the images' periodic tick.
//!
//! ```text
//!  thread                                         control interrupt
//!  ------                                         -----------------
//!  BoardLinkState::on_byte -> answer bytes         BoardLinkState::period(drive on board)
//!  BoardLinkState::periods (a watchdog clock)        ControlLoop::period, Capture::record,
//!                                                    DriveStatus::update
//! ```
//!
//! Board-specific start-up and fault handling stay with the board (its `init`, its
//! safe state, and the fault vectors an image expands once: `esc1_fault_handlers!`,
//! `mps2_fault_handlers!`). What a new board implements: `docs/new-board.md`.
//! Every critical section here masks with PRIMASK (`cortex_m::interrupt::free`): none
//! relies on interrupt priorities.

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cortex_m::interrupt::{self, CriticalSection, Mutex};
use cortex_m::peripheral::scb::SystemHandler;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{SCB, SYST};
use dcfo::capture::{Capture, CaptureScalar};
use dcfo::link::board::{BoardTelemetry, CaptureChunk};
use dcfo::link::encode;

use crate::board::{PhaseSensors, PowerStage};
use crate::board_link::{BoardAnswer, BoardLinkServer, DriveStatus, LinkClock, answer};
use crate::control::{ControlLoop, Setpoints};

/// State that an interrupt owns: empty until `main` [`install`]s it, then borrowed only
/// in critical sections that never nest.
///
/// For a large state, install a `&'static mut` to it (from `cortex_m::singleton!`, which
/// keeps it in `.bss`): an empty `Slot` of a reference is all zeros and lives in `.bss`
/// too, where `Option<T>` of a state with a niche (a `bool`, an enum) is not all zeros,
/// and the whole state would be copied from flash into `.data` at reset.
pub type Slot<T> = Mutex<RefCell<Option<T>>>;

/// An empty [`Slot`], for a `static` (const).
pub const fn slot<T>() -> Slot<T> {
    Mutex::new(RefCell::new(None))
}

/// Puts `value` into `slot` (in a critical section). `false` if the slot was borrowed,
/// which cannot happen before the interrupts that use it are enabled.
pub fn install<T>(slot: &Slot<T>, value: T) -> bool {
    interrupt::free(|cs| match slot.borrow(cs).try_borrow_mut() {
        Ok(mut s) => {
            *s = Some(value);
            true
        }
        Err(_) => false,
    })
}

/// Runs `f` on the state in `slot` in a critical section (not at all while the slot is
/// empty). Every user borrows the state only inside such a section and never from within
/// another, so the borrow cannot fail; if it did, `f` is skipped (no panic) and `false`
/// returned.
pub fn with_slot<T>(slot: &Slot<T>, f: impl FnOnce(&mut T)) -> bool {
    interrupt::free(|cs| match slot.borrow(cs).try_borrow_mut() {
        Ok(mut guard) => {
            if let Some(s) = guard.as_mut() {
                f(s);
            }
            true
        }
        Err(_) => false,
    })
}

/// The control interrupt's state in a drive image: the control loop and the board it
/// runs on (a power stage, or the virtual motor).
pub struct DriveOnBoard<T, B> {
    /// The drive and its setpoint handling.
    pub control: ControlLoop<T>,
    /// Sensors and power stage ([`PhaseSensors`] + [`PowerStage`]).
    pub board: B,
}

/// The capture of a drive image's board link (`N` samples), behind a critical section:
/// a `static` of its own ([`capture_cell`]). An empty capture is all zero bytes, so the
/// static starts in `.bss` (zeroed at reset) and costs no flash; inside
/// [`BoardLinkState`], whose status is not all zeros, it would be copied from flash into
/// `.data`.
pub type CaptureCell<const N: usize> = Mutex<RefCell<Capture<N>>>;

/// An empty [`CaptureCell`], for a `static` (const).
pub const fn capture_cell<const N: usize>() -> CaptureCell<N> {
    Mutex::new(RefCell::new(Capture::new()))
}

/// What the control interrupt leaves for the board link, and the thread's side of that
/// link: the capture (`N` samples, a [`CaptureCell`] of its own) and the last step's
/// status, each behind a critical section. Constant-initialised in place (a `static`):
/// the capture never passes through the stack.
pub struct BoardLinkState<const N: usize> {
    capture: &'static CaptureCell<N>,
    status: Mutex<RefCell<DriveStatus>>,
}

impl<const N: usize> BoardLinkState<N> {
    /// The board link on `capture`, with a disabled drive's status.
    pub const fn new(capture: &'static CaptureCell<N>) -> Self {
        BoardLinkState { capture, status: Mutex::new(RefCell::new(DriveStatus::new())) }
    }

    /// One control period, from the control interrupt inside its critical section `cs`:
    /// [`ControlLoop::period`] on the board, then [`Capture::record`] and
    /// [`DriveStatus::update`] (skipped should the thread hold them, which it cannot:
    /// its sections do not nest with this one). Bounded: the drive's step and O(1) more.
    pub fn period<T: CaptureScalar, B: PhaseSensors + PowerStage>(
        &self,
        cs: &CriticalSection,
        c: &mut DriveOnBoard<T, B>,
        setpoints: &Setpoints,
    ) {
        let (out, sample) = c.control.period(&mut c.board, setpoints);
        if let (Ok(mut capture), Ok(mut status)) =
            (self.capture.borrow(cs).try_borrow_mut(), self.status.borrow(cs).try_borrow_mut())
        {
            capture.record(&out);
            status.update(&out, &sample, c.control.base(), c.control.position_report(setpoints));
        }
    }

    /// The last step's status, copied in a critical section (`None` if it was borrowed).
    pub fn status(&self) -> Option<DriveStatus> {
        interrupt::free(|cs| self.status.borrow(cs).try_borrow().map(|s| *s).ok())
    }

    /// Control periods run so far (the status's count; 0 if it could not be read): the
    /// command watchdog's clock ([`LinkClock::periods`]).
    pub fn periods(&self) -> u32 {
        interrupt::free(|cs| self.status.borrow(cs).try_borrow().map(|s| s.periods).unwrap_or(0))
    }

    /// The thread's side of the board link, one received byte at a time: a complete
    /// command goes to `server` (which applies it to `setpoints`), its answer
    /// (telemetry, or capture samples) is encoded into `wire` and returned for the
    /// caller to send. `None` while no command is complete, or should the capture or
    /// status be busy (the host then sees no answer and asks again). The critical
    /// section copies at most one chunk of samples. `now` is the command watchdog's
    /// clocks ([`BoardLinkServer::on_byte`]).
    pub fn on_byte<'w>(
        &self,
        server: &mut BoardLinkServer,
        byte: u8,
        setpoints: &Setpoints,
        now: LinkClock,
        wire: &'w mut [u8; CaptureChunk::WIRE_LEN],
    ) -> Option<&'w [u8]> {
        let command = server.on_byte(byte, setpoints, now)?;
        let reply = interrupt::free(|cs| {
            match (self.capture.borrow(cs).try_borrow_mut(), self.status.borrow(cs).try_borrow()) {
                (Ok(mut capture), Ok(status)) => Some(answer(&command, &mut capture, &status, setpoints)),
                _ => None,
            }
        });
        let encoded = match reply? {
            BoardAnswer::Telemetry(t) => encode::<BoardTelemetry>(&t, wire),
            BoardAnswer::Chunk(c) => encode::<CaptureChunk>(&c, wire),
        };
        let n = encoded.ok()?;
        wire.get(..n)
    }
}

/// Starts SysTick: `priority` (an NVIC priority byte, 0x00 highest), `clock` (the core
/// clock, or the board's external reference, e.g. HCLK / 8 on the STM32G4) and `reload`
/// (ticks per period minus one, at most 2^24 - 1). The interrupt is enabled last, with
/// its handler's state in place beforehand.
pub fn start_systick(syst: &mut SYST, scb: &mut SCB, priority: u8, clock: SystClkSource, reload: u32) {
    // SAFETY: set before SysTick is enabled (below); changing a priority is unsafe only
    // for critical sections built on priorities, and every critical section in this
    // firmware masks with PRIMASK instead.
    unsafe { scb.set_priority(SystemHandler::SysTick, priority) };
    syst.set_clock_source(clock);
    syst.set_reload(reload);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
}

/// Watches the control interrupt from a slower periodic one (e.g. SysTick at a lower
/// priority): the control interrupt counts its periods ([`StallCheck::period`]), the
/// periodic check ([`StallCheck::check`]) finds whether any ran since its previous call.
/// `checks` calls in a row without one (between `checks` and `checks + 1` check periods
/// of silence) are a stall. The command watchdog counts control periods, so it cannot see
/// the control interrupt stop. Atomics only: any context may call any method.
pub struct StallCheck {
    /// Control periods run (wrapping): the thread's time base.
    periods: AtomicU32,
    /// `periods` at the last check.
    seen: AtomicU32,
    /// Checks in a row that saw no new period.
    count: AtomicU32,
    /// Set once a stall was handled.
    stalled: AtomicBool,
    checks: u32,
}

impl StallCheck {
    /// A check that declares a stall after `checks` silent check periods in a row.
    pub const fn new(checks: u32) -> Self {
        StallCheck {
            periods: AtomicU32::new(0),
            seen: AtomicU32::new(0),
            count: AtomicU32::new(0),
            stalled: AtomicBool::new(false),
            checks,
        }
    }

    /// One control period has run (from the control interrupt, every period).
    pub fn period(&self) {
        self.periods.fetch_add(1, Ordering::Relaxed);
    }

    /// Control periods run so far (wrapping).
    pub fn periods(&self) -> u32 {
        self.periods.load(Ordering::Relaxed)
    }

    /// Starts the count from now (call before the periodic check is enabled).
    pub fn arm(&self) {
        self.seen.store(self.periods(), Ordering::Relaxed);
    }

    /// The periodic check: on a stall runs `on_stall` (switch the bridge off, mask the
    /// control interrupt) and then marks the stall for [`StallCheck::stalled`]. A load,
    /// a swap and a compare otherwise.
    pub fn check(&self, on_stall: impl FnOnce()) {
        let now = self.periods();
        if self.seen.swap(now, Ordering::Relaxed) != now {
            self.count.store(0, Ordering::Relaxed);
        } else if self.count.fetch_add(1, Ordering::Relaxed) + 1 >= self.checks {
            on_stall();
            self.stalled.store(true, Ordering::Relaxed);
        }
    }

    /// Whether a stall was found (and handled): the thread then stops and says why.
    pub fn stalled(&self) -> bool {
        self.stalled.load(Ordering::Relaxed)
    }
}
