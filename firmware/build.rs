//! Linker set-up for the firmware images (arm only; host builds do nothing).
//!
//! The workspace-root `memory.x` is `INCLUDE board_memory.x`: this script writes the
//! selected board's MEMORY regions under that name into `OUT_DIR` and puts `OUT_DIR` on
//! the linker search path, so cortex-m-rt's own `link.x` links the images. The board is
//! the cargo feature: `mps2` (QEMU MPS2 AN385/AN386) or `esc1` (ST B-G431B-ESC1); one
//! build links for one board. The workspace's `.cargo/config.toml` already passes
//! `-Tlink.x` for the thumb targets; it is added here only when the rustflags lack it
//! (given twice, the script's symbols would be defined twice).

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=memory/mps2.x");
    println!("cargo:rerun-if-changed=memory/stm32g431cb.x");
    if env::var("CARGO_CFG_TARGET_ARCH").as_deref() != Ok("arm") {
        return;
    }
    let mps2 = env::var_os("CARGO_FEATURE_MPS2").is_some();
    let esc1 = env::var_os("CARGO_FEATURE_ESC1").is_some();
    let memory: &[u8] = match (mps2, esc1) {
        (true, false) => include_bytes!("memory/mps2.x"),
        (false, true) => include_bytes!("memory/stm32g431cb.x"),
        (true, true) => panic!("features `mps2` and `esc1` select different boards: build one at a time"),
        // The library alone (e.g. `cargo build --target ...` without an image) links nothing.
        (false, false) => return,
    };
    let Some(out) = env::var_os("OUT_DIR").map(PathBuf::from) else {
        panic!("cargo sets OUT_DIR for build scripts");
    };
    if let Err(e) = fs::write(out.join("board_memory.x"), memory) {
        panic!("writing board_memory.x to {}: {e}", out.display());
    }
    println!("cargo:rustc-link-search={}", out.display());
    let rustflags = env::var("CARGO_ENCODED_RUSTFLAGS").unwrap_or_default();
    if !rustflags.split('\x1f').any(|flag| flag.contains("-Tlink.x")) {
        println!("cargo:rustc-link-arg-examples=-Tlink.x");
    }
    if esc1 {
        // defmt's symbol table for the RTT logger.
        println!("cargo:rustc-link-arg-examples=-Tdefmt.x");
    }
}
