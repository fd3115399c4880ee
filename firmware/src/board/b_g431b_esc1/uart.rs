//! USART2 on the ST-LINK virtual COM port: [`Esc1Uart`] (`embedded_io::{Read, Write}`).

use stm32g4::stm32g431 as pac;

use super::DEFAULT_BAUD;
use super::pins::{PIN_UART_RX, PIN_UART_TX};
use crate::board::esc1_settings::SYSCLK_HZ;

/// Interrupt of the UART (RX-not-empty when enabled with [`Esc1Uart::listen_rx`]).
pub const UART_IRQ: pac::Interrupt = pac::Interrupt::USART2;

// =================================================================================================
// USART2 — RM0440 ch. 37 "USART": §37.5.7 baud rate (BRR = f_ck / baud, OVER8 = 0),
// USART_CR1/ISR/ICR/RDR/TDR. FIFO disabled.
// =================================================================================================

/// UART receive errors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UartError {
    /// Receiver overrun (a byte was lost).
    Overrun,
    /// Framing error (stop bit missing; wrong baud?).
    Framing,
    /// Noise detected on a received bit.
    Noise,
    /// Parity error (cannot happen with 8N1, reported for completeness).
    Parity,
}

impl embedded_io::Error for UartError {
    fn kind(&self) -> embedded_io::ErrorKind {
        match self {
            UartError::Overrun => embedded_io::ErrorKind::OutOfMemory,
            _ => embedded_io::ErrorKind::InvalidData,
        }
    }
}

/// USART2, 8 data bits, no parity, 1 stop bit, on PB3 (TX) / PB4 (RX).
pub struct Esc1Uart {
    usart: pac::USART2,
}

impl Esc1Uart {
    pub(super) fn new(usart: pac::USART2, gpiob: &pac::GPIOB, baud: u32, rx_irq: bool) -> Self {
        pin_af!(gpiob, PIN_UART_TX, 3);
        pin_af!(gpiob, PIN_UART_RX, 3);
        gpiob.pupdr().modify(|_, w| w.pupdr(PIN_UART_RX.pin).pull_up());

        let baud = if baud == 0 { DEFAULT_BAUD } else { baud };
        // Rounded BRR, >= 16 required with OVER8 = 0 (max ~10.6 Mbit/s at 170 MHz).
        let brr = (SYSCLK_HZ + baud / 2) / baud;
        let brr = brr.clamp(16, 0xFFFF) as u16;
        usart.cr1().write(|w| w.ue().clear_bit());
        usart.brr().write(|w| w.brr().set(brr));
        usart.cr1().write(|w| {
            w.te().set_bit();
            w.re().set_bit();
            w.rxneie().bit(rx_irq);
            w.ue().set_bit()
        });
        Self { usart }
    }

    /// Enables or disables the RX-not-empty interrupt (vector [`UART_IRQ`]).
    pub fn listen_rx(&mut self, enable: bool) {
        self.usart.cr1().modify(|_, w| w.rxneie().bit(enable));
    }

    /// Non-blocking read: `Ok(Some(byte))`, `Ok(None)` if nothing arrived, or a receive error
    /// (the error flag is cleared; the pending byte, if any, stays readable).
    pub fn try_read_byte(&mut self) -> Result<Option<u8>, UartError> {
        let isr = self.usart.isr().read();
        if isr.ore().bit_is_set() {
            self.usart.icr().write(|w| w.orecf().clear());
            return Err(UartError::Overrun);
        }
        if isr.fe().bit_is_set() {
            self.usart.icr().write(|w| w.fecf().clear());
            return Err(UartError::Framing);
        }
        if isr.nf().bit_is_set() {
            self.usart.icr().write(|w| w.ncf().clear());
            return Err(UartError::Noise);
        }
        if isr.pe().bit_is_set() {
            self.usart.icr().write(|w| w.pecf().clear());
            return Err(UartError::Parity);
        }
        if isr.rxne().bit_is_set() { Ok(Some(self.usart.rdr().read().rdr().bits() as u8)) } else { Ok(None) }
    }

    /// Blocking write of one byte (waits for TXE).
    pub fn write_byte(&mut self, b: u8) {
        while self.usart.isr().read().txe().bit_is_clear() {}
        self.usart.tdr().write(|w| w.tdr().set(u16::from(b)));
    }
}

impl embedded_io::ErrorType for Esc1Uart {
    type Error = UartError;
}

impl embedded_io::Write for Esc1Uart {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(buf.len())
    }

    /// Every byte, blocking: the trait's default loops on `write` and panics on a
    /// zero-length write, a path the optimiser cannot always prove dead.
    fn write_all(&mut self, buf: &[u8]) -> Result<(), Self::Error> {
        for &b in buf {
            self.write_byte(b);
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        while self.usart.isr().read().tc().bit_is_clear() {}
        Ok(())
    }
}

impl embedded_io::Read for Esc1Uart {
    /// Blocks until at least one byte is available, then returns what is there (no further wait).
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let mut n = 0;
        for slot in buf.iter_mut() {
            let b = loop {
                match self.try_read_byte() {
                    Ok(Some(b)) => break Some(b),
                    Ok(None) if n == 0 => continue,
                    Ok(None) => break None,
                    // Bytes already taken are not lost: report them, the error shows next call.
                    Err(_) if n > 0 => break None,
                    Err(e) => return Err(e),
                }
            };
            match b {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }
}

impl embedded_io::ReadReady for Esc1Uart {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.usart.isr().read().rxne().bit_is_set())
    }
}

impl embedded_io::WriteReady for Esc1Uart {
    fn write_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(self.usart.isr().read().txe().bit_is_set())
    }
}
