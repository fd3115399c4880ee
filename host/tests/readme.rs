//! The README's figures are the tools' own: every generated block equals its file under
//! `results/` (written by `dcfo results render` from a tool's output), and the cost
//! table equals what `bench/recorded.json` renders to. No tool runs here; CI checks
//! `results/paper.md` against its own `dcfo paper` run (`.ci/run`), and
//! `results/regenerate` rewrites them all.

use dcfo_host::commands::results::{Input, README, RESULTS_DIR, Table, blocks, readme_differences};
use std::path::{Path, PathBuf};

/// The workspace root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("host/ has a parent").to_path_buf()
}

fn readme() -> String {
    std::fs::read_to_string(root().join(README)).expect("README.md is readable")
}

#[test]
fn every_generated_block_equals_its_results_file() {
    let differences = readme_differences(&readme(), &root()).expect("the README's blocks parse");
    assert!(
        differences.is_empty(),
        "the README's generated blocks are not the results files (run `results/regenerate`, or \
         `cargo run --release -p dcfo-host -- results readme` after editing results/):\n{}",
        differences.join("\n")
    );
}

#[test]
fn every_table_has_its_results_file_and_its_block() {
    let names: Vec<String> =
        blocks(&readme()).expect("the README's blocks parse").into_iter().map(|b| b.name).collect();
    for table in Table::ALL {
        assert!(table.path(&root()).is_file(), "no {}", table.path(&root()).display());
        assert!(names.iter().any(|n| n == table.name()), "the README has no block `{}`", table.name());
    }
    for entry in std::fs::read_dir(root().join(RESULTS_DIR)).expect("results/ is readable") {
        let path = entry.expect("a directory entry").path();
        if path.extension().is_some_and(|e| e == "md") {
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
            assert!(
                Table::from_name(stem).is_some(),
                "{} is no table `dcfo results` renders",
                path.display()
            );
        }
    }
}

/// The cost table is rendered from the recorded budget figures, which `bench_qemu
/// --record` writes: checked here, not only when the results are regenerated.
#[test]
fn the_cost_table_is_the_recorded_budget() {
    let recorded = root().join("bench/recorded.json");
    let input = Input::read(recorded.to_str().expect("a UTF-8 path")).expect("bench/recorded.json reads");
    let rendered = Table::Cost.render(&[input]).expect("bench/recorded.json renders");
    let committed = std::fs::read_to_string(Table::Cost.path(&root())).expect("results/cost.md is readable");
    assert_eq!(
        committed, rendered,
        "results/cost.md is not bench/recorded.json's table: run `results/regenerate cost`"
    );
}

/// The check above can fail: a block changed by one character is reported.
#[test]
fn a_changed_block_is_reported() {
    let text = readme();
    let block =
        blocks(&text).expect("blocks parse").into_iter().find(|b| !b.content.is_empty()).expect("a block");
    let line = text.lines().nth(block.line).expect("the block's first line");
    let changed = text.replacen(line, &format!("{line} "), 1);
    let differences = readme_differences(&changed, &root()).expect("blocks parse");
    assert!(differences.iter().any(|d| d.contains(&format!("`{}`", block.name))), "{differences:?}");
}

/// The README is the front door, not a notebook (issue 37): what was measured and tried
/// goes to `results/`, `docs/` and `CHANGELOG.md`.
#[test]
fn the_readme_stays_short() {
    let lines = readme().lines().count();
    assert!(lines <= 400, "README.md has {lines} lines; the limit is 400");
}
