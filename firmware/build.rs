//! Linker set-up for the firmware binaries (arm only; host builds do nothing).
//!
//! The workspace-root `memory.x` is `INCLUDE board_memory.x`: this script writes the
//! board's MEMORY regions under that name into `OUT_DIR` and puts `OUT_DIR` on the linker
//! search path, so cortex-m-rt's own `link.x` links this crate's binaries for QEMU's
//! mps2-an386. The workspace's `.cargo/config.toml` already passes `-Tlink.x` for the
//! thumb targets; it is added here only when the rustflags lack it (given twice, the
//! script's symbols would be defined twice).

use std::env;
use std::fs;
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=memory/mps2_an386.x");
    if env::var("CARGO_CFG_TARGET_ARCH").as_deref() != Ok("arm") {
        return;
    }
    let Some(out) = env::var_os("OUT_DIR").map(PathBuf::from) else {
        panic!("cargo sets OUT_DIR for build scripts");
    };
    if let Err(e) = fs::write(out.join("board_memory.x"), include_bytes!("memory/mps2_an386.x")) {
        panic!("writing board_memory.x to {}: {e}", out.display());
    }
    println!("cargo:rustc-link-search={}", out.display());
    let rustflags = env::var("CARGO_ENCODED_RUSTFLAGS").unwrap_or_default();
    if !rustflags.split('\x1f').any(|flag| flag.contains("-Tlink.x")) {
        println!("cargo:rustc-link-arg-bins=-Tlink.x");
    }
}
