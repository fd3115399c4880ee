//! What the tests share: whether the QEMU tests run (the tools are here, or
//! `DCFO_REQUIRE_QEMU=1` makes a missing tool a failure, as CI sets it), the workspace
//! root, the HIL image they build, and a map over independent runs on every core.
// Each test crate uses part of it.
#![allow(dead_code)]

use dcfo_host::qemu::{QemuCpu, missing_tools};
use std::path::PathBuf;

/// The workspace root (the firmware crate builds from there).
pub fn workspace() -> PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

/// `true` when the QEMU tests for `cpu` can run; otherwise prints why and gives `false`,
/// or fails when `DCFO_REQUIRE_QEMU=1`.
pub fn qemu_runs(cpu: QemuCpu) -> bool {
    match missing_tools(cpu) {
        None => true,
        Some(why) => {
            assert!(std::env::var("DCFO_REQUIRE_QEMU").as_deref() != Ok("1"), "QEMU required: {why}");
            println!("skipped: {why}");
            false
        }
    }
}

/// The HIL firmware (`qemu_hil`) for `cpu`, built; `None` when the test must skip.
pub fn hil_firmware(cpu: QemuCpu) -> Option<PathBuf> {
    qemu_runs(cpu)
        .then(|| dcfo_host::hil_link::build_qemu_firmware(&workspace(), cpu).expect("firmware builds"))
}

/// `f` of every item, in order, the items split over as many scoped threads as the
/// machine has cores: for a test made of independent closed-loop runs, which would
/// otherwise leave the other cores idle while it runs alone.
pub fn map_on_every_core<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let chunk = items.len().div_ceil(cores).max(1);
    let f = &f;
    std::thread::scope(|scope| {
        let workers: Vec<_> = items
            .chunks(chunk)
            .map(|part| scope.spawn(move || part.iter().map(f).collect::<Vec<R>>()))
            .collect();
        // A failed assertion in a worker fails the test with its own message.
        workers.into_iter().flat_map(|w| w.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect()
    })
}
