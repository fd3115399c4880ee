//! The defmt global logger over SEGGER RTT for the ESC1 images, without a path to a
//! panic and without blocking.
//!
//! Why not `defmt-rtt`: its `acquire` panics when the logger is taken again from an
//! interrupt ("defmt logger taken reentrantly"), in both of its modes, so the images
//! linked the panic machinery for it (`.ci/no-panic`). Here a nested log frame (an
//! interrupt that logs while the thread is in the middle of a frame) is dropped instead,
//! and a full buffer drops bytes instead of waiting for the probe: a logger never holds
//! up the drive. (defmt frames are delimited: the host's decoder resynchronises after a
//! dropped byte, and reports the frame it lost.) probe-rs' request for blocking mode is
//! therefore not honoured.
//!
//! The RTT control block (the `_SEGGER_RTT` symbol the probe looks up) is SEGGER's
//! layout: the 16-byte id `"SEGGER RTT"`, the number of up and down channels, then per
//! channel its name, buffer address, size, write offset (ours), read offset (the
//! probe's) and flags. One up channel, named `defmt`, of [`BUFFER_SIZE`] bytes.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU8, AtomicU32, Ordering};

use critical_section::Mutex;

/// Bytes of the up channel's ring (one stays free to tell full from empty). The images
/// log a burst at start-up (eight frames, each a format index and its arguments, the
/// motor image's records the largest: about 300 bytes in all) and then a frame per state
/// change: half a KiB holds the burst until a probe attaches, within the 8 KiB of static
/// RAM the ESC1 image is allowed.
pub const BUFFER_SIZE: usize = 512;

/// RTT channel mode "no block, trim": what does not fit is dropped.
const MODE_NO_BLOCK_TRIM: u32 = 1;

/// One RTT up channel as the probe reads it.
#[repr(C)]
struct UpChannel {
    name: *const u8,
    buffer: *const AtomicU8,
    size: u32,
    write: AtomicU32,
    read: AtomicU32,
    flags: AtomicU32,
}

/// SEGGER's RTT control block with one up channel and no down channel.
#[repr(C)]
struct ControlBlock {
    id: [u8; 16],
    max_up_channels: u32,
    max_down_channels: u32,
    up: UpChannel,
}

// SAFETY: the two raw pointers are written once, at compile time, and only the debug
// probe follows them (through the memory bus); this program never dereferences them.
// Every field that changes at run time is an atomic.
unsafe impl Sync for ControlBlock {}

static NAME: [u8; 6] = *b"defmt\0";
static BUFFER: [AtomicU8; BUFFER_SIZE] = [const { AtomicU8::new(0) }; BUFFER_SIZE];

// SAFETY: `no_mangle` exports the name the probe looks for; no other symbol in the
// image has it (defmt-rtt and rtt-target are not linked).
#[unsafe(no_mangle)]
static _SEGGER_RTT: ControlBlock = ControlBlock {
    id: *b"SEGGER RTT\0\0\0\0\0\0",
    max_up_channels: 1,
    max_down_channels: 0,
    up: UpChannel {
        name: NAME.as_ptr(),
        buffer: BUFFER.as_ptr(),
        size: BUFFER_SIZE as u32,
        write: AtomicU32::new(0),
        read: AtomicU32::new(0),
        flags: AtomicU32::new(MODE_NO_BLOCK_TRIM),
    },
};

/// Log frames open: 1 while one context writes its frame, more while contexts that
/// interrupted it try to log too (their frames are dropped).
static DEPTH: AtomicU32 = AtomicU32::new(0);
/// The frame encoder of the context that holds the logger.
static ENCODER: Mutex<RefCell<defmt::Encoder>> = Mutex::new(RefCell::new(defmt::Encoder::new()));
/// Frames dropped because another context was logging (diagnostics).
static DROPPED_FRAMES: AtomicU32 = AtomicU32::new(0);

/// Log frames dropped because they were started while another context was logging.
pub fn dropped_frames() -> u32 {
    DROPPED_FRAMES.load(Ordering::Relaxed)
}

/// Copies `bytes` into the ring as far as there is room; the rest is dropped.
fn rtt_write(bytes: &[u8]) {
    let up = &_SEGGER_RTT.up;
    let read = up.read.load(Ordering::Acquire) as usize;
    let mut write = up.write.load(Ordering::Relaxed) as usize;
    for &b in bytes {
        let next = if write + 1 >= BUFFER_SIZE { 0 } else { write + 1 };
        if next == read {
            break;
        }
        let Some(slot) = BUFFER.get(write) else { break };
        slot.store(b, Ordering::Relaxed);
        write = next;
    }
    // The probe reads up to `write`: the bytes are stored before it moves.
    up.write.store(write as u32, Ordering::Release);
}

/// Runs `f` on the encoder, only in the context that holds the logger (no nesting).
fn with_encoder(f: impl FnOnce(&mut defmt::Encoder)) {
    if DEPTH.load(Ordering::Relaxed) != 1 {
        return;
    }
    critical_section::with(|cs| {
        if let Ok(mut encoder) = ENCODER.borrow(cs).try_borrow_mut() {
            f(&mut encoder);
        }
    });
}

#[defmt::global_logger]
struct Logger;

// SAFETY: `acquire` is safe to call from any context: a context that finds the logger
// taken only counts itself in `DEPTH` and writes nothing until its `release`. A context
// that interrupts another runs to completion before the other resumes (one core), so
// the depth is 1 exactly while the holder writes.
unsafe impl defmt::Logger for Logger {
    fn acquire() {
        if DEPTH.fetch_add(1, Ordering::Acquire) == 0 {
            with_encoder(|e| e.start_frame(rtt_write));
        } else {
            DROPPED_FRAMES.fetch_add(1, Ordering::Relaxed);
        }
    }

    unsafe fn flush() {
        // Never waits for the probe (see the module documentation).
    }

    unsafe fn release() {
        with_encoder(|e| e.end_frame(rtt_write));
        // Never below zero, even for a release without its acquire.
        let _ = DEPTH.fetch_update(Ordering::Release, Ordering::Relaxed, |d| d.checked_sub(1));
    }

    unsafe fn write(bytes: &[u8]) {
        with_encoder(|e| e.write(bytes, rtt_write));
    }
}
