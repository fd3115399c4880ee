//! Lock-step HIL firmware for the ST B-G431B-ESC1: the drive of the simulated paper axis
//! (`DriveConfig::paper_axis`, the settings of `dcfo hil`'s plant, as the QEMU image runs
//! them) behind the `dcfo::link` protocol on USART2, the ST-LINK virtual COM port at
//! 921600 8N1. The power stage is initialised with the bridge off and stays off: the
//! motor here is the host's simulation. **Not tried on hardware** (none here).
//!
//! | context | priority | work | budget |
//! |---|---|---|---|
//! | SysTick, every 50 ms | 0x80 | link watchdog: `HilServer::watchdog_period` | a counter and a compare (not measured) |
//! | thread | — | polls USART2; each byte to `HilServer::on_byte` (an in-order frame runs one `Drive::step`) in a critical section; the answer out | the link sets the pace: a round trip is 73 bytes, about 0.8 ms at 921600 bit/s |
//!
//! A silent link (10 watchdog periods, 0.5 s) switches an active drive off, as on QEMU.
//! Nothing in the image can panic (`.ci/no-panic`); an initialisation that cannot
//! complete and a HardFault switch the bridge off (TIM1 MOE clear) and stop.
//! ```sh
//! cargo run -p dcfo-firmware --release --features esc1 --example b_g431b_esc1_hil --target thumbv7em-none-eabihf
//! cargo run --release -p dcfo-host -- hil --port /dev/ttyACM0 --baud 921600 --check
//! ```
#![cfg_attr(target_arch = "arm", no_std)]
#![cfg_attr(target_arch = "arm", no_main)]

#[cfg(not(target_arch = "arm"))]
fn main() {
    eprintln!("b_g431b_esc1_hil is firmware: build it with `--target thumbv7em-none-eabihf`");
}

#[cfg(target_arch = "arm")]
mod firmware {
    use cortex_m::peripheral::syst::SystClkSource;
    use cortex_m_rt::{entry, exception};
    use dcfo::algorithms::observer::ObserverKind;
    use dcfo::drive::{Drive, DriveConfig};
    use dcfo::motor::MotorParams;
    use dcfo::num::units::Base;
    use dcfo_firmware::board::b_g431b_esc1::{self as esc1, Esc1Config, SYSCLK_HZ, stop};
    use dcfo_firmware::hil::HilServer;
    use dcfo_firmware::queue::{Producer, Queue};
    use dcfo_firmware::runtime::{Slot, install, slot, start_systick, with_slot};
    use dcfo_firmware::stack;
    use embedded_io::Write as _;
    use stm32g4::stm32g431 as pac;

    const BAUD: u32 = 921_600;
    /// Watchdog ticks per second (50 ms); SysTick's reload (24 bits) fits at 170 MHz / 8.
    const WATCHDOG_TICK_HZ: u32 = 20;
    /// Two answers, or a commissioning report.
    const TX_QUEUE_BYTES: usize = dcfo_firmware::hil::tx_queue_bytes(2);
    /// SysTick (the link watchdog) priority.
    const PRIORITY_WATCHDOG: u8 = 0x80;

    struct Hil {
        server: HilServer<f32>,
        tx: Producer<'static, u8, TX_QUEUE_BYTES>,
    }

    static HIL: Slot<Hil> = slot();

    #[entry]
    fn main() -> ! {
        let Some(dp) = pac::Peripherals::take() else {
            stop(defmt::intern!("device peripherals taken twice"))
        };
        let Some(mut cp) = cortex_m::Peripherals::take() else {
            stop(defmt::intern!("core peripherals taken twice"))
        };
        // The stack (below the statics, flip-link): painted, so that a probe can read its
        // high-water mark, and its lowest bytes made a fault through the MPU, in case
        // the bus does not fault just below RAM.
        stack::paint();
        let guarded = stack::guard(&mut cp.MPU);
        // The bridge stays off: init leaves MOE clear and nothing here enables it.
        let board = match esc1::init(dp, &Esc1Config { baud: BAUD, ..Esc1Config::default() }) {
            Ok(board) => board,
            Err(e) => stop(e),
        };
        let mut uart = board.uart;
        let motor = MotorParams::paper();
        let drive = match Drive::<f32>::new(&motor, &DriveConfig::paper_axis(ObserverKind::Dcfo), &Base::SI) {
            Ok(d) => d,
            Err(e) => stop(e.field),
        };
        let Some(queue) = cortex_m::singleton!(: Queue<u8, TX_QUEUE_BYTES> = Queue::new()) else {
            stop(defmt::intern!("transmit queue taken twice"))
        };
        let (producer, mut consumer) = queue.split();
        if !install(&HIL, Hil { server: HilServer::new(drive), tx: producer }) {
            stop(defmt::intern!("HIL state busy at start-up"));
        }

        // HCLK / 8.
        start_systick(
            &mut cp.SYST,
            &mut cp.SCB,
            PRIORITY_WATCHDOG,
            SystClkSource::External,
            SYSCLK_HZ / 8 / WATCHDOG_TICK_HZ - 1,
        );
        defmt::info!("B-G431B-ESC1 HIL target ready at {} bit/s", BAUD);
        defmt::info!("stack: {} bytes, MPU guard {}", stack::bounds().1 - stack::bounds().0, guarded);

        loop {
            match uart.try_read_byte() {
                // (A byte that cannot reach the state is dropped: the frame's CRC
                // rejects it and the link counts it.)
                Ok(Some(byte)) => {
                    with_slot(&HIL, |h| h.server.on_byte(byte, &mut h.tx));
                }
                Ok(None) => {}
                // A lost or garbled byte: the frame's CRC rejects it, the link counts it.
                Err(e) => defmt::warn!("USART2: {}", defmt::Debug2Format(&e)),
            }
            while let Some(byte) = consumer.dequeue() {
                let _ = uart.write_all(&[byte]);
            }
        }
    }

    /// The link watchdog, every 50 ms.
    #[exception]
    fn SysTick() {
        with_slot(&HIL, |h| {
            h.server.watchdog_period();
        });
    }

    dcfo_firmware::esc1_fault_handlers!();
}
