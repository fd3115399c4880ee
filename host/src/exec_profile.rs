//! Where a firmware image's instructions go: QEMU's translation and execution log read
//! against the image's symbols, one *window* per call of a marker function.
//!
//! QEMU prints, with `-d in_asm,exec,nochain` (on stderr unless `-D` names a file):
//! - at each translation, `IN: <symbol>` and then one line per guest instruction,
//!   `0x<address>:  <encoding>  <mnemonic>`, ended by a blank line: the translation
//!   block (TB) starting at the first address and its instruction count;
//! - at each execution of a block (`nochain`: every one is logged), `Trace <cpu>: <host
//!   pointer> [<cs_base>/<pc>/<flags>/<cflags>] <symbol>`.
//!
//! A block may be translated again shorter at the same address (under `-icount` an
//! instruction budget can end one early); the longest translation is counted, which
//! over-counts those rare truncated executions by at most a block. A window opens when a
//! block of the marker function runs (the bench's `stage_step_brief`, the timed call of
//! one `Drive::step`) and closes when a block of the function that called it runs again;
//! every block executed in between is counted to the function holding its address
//! (inlined code counts to its caller). Calls into the compiler's soft-float and
//! conversion routines are also counted to the last function of the image's own code
//! that ran before them. The result: per function, the instructions of the costliest
//! window and the mean over all windows.
//!
//! Checked against `bench_qemu`'s SysTick counts of the same run: the windows' mean and
//! maximum are those counts plus the bench's call of the marker (tens of instructions).

use std::collections::HashMap;

/// The image's code symbols: start addresses (Thumb bit cleared) and names, sorted.
#[derive(Debug, Default)]
pub struct Symbols {
    starts: Vec<u32>,
    names: Vec<String>,
}

impl Symbols {
    /// From `arm-none-eabi-nm -n -C --defined-only` output: the `T`/`t` lines
    /// (`<hex address> <type> <name>`); other lines are skipped.
    pub fn from_nm(text: &str) -> Symbols {
        let mut pairs: Vec<(u32, String)> = text
            .lines()
            .filter_map(|line| {
                let mut words = line.splitn(3, ' ');
                let address = u32::from_str_radix(words.next()?, 16).ok()?;
                let kind = words.next()?;
                let name = words.next()?;
                matches!(kind, "T" | "t").then(|| (address & !1, name.to_owned()))
            })
            .collect();
        pairs.sort_by_key(|p| p.0);
        let (starts, names) = pairs.into_iter().unzip();
        Symbols { starts, names }
    }

    /// Number of symbols.
    pub fn len(&self) -> usize {
        self.starts.len()
    }

    /// `true` without symbols.
    pub fn is_empty(&self) -> bool {
        self.starts.is_empty()
    }

    /// Index of the symbol holding `pc` (the last one starting at or below it).
    pub fn index_of(&self, pc: u32) -> Option<usize> {
        self.starts.partition_point(|&s| s <= pc).checked_sub(1)
    }

    /// The name of symbol `index`.
    pub fn name(&self, index: usize) -> &str {
        self.names.get(index).map_or("?", String::as_str)
    }

    /// Index of the first symbol whose name contains `part`.
    pub fn find(&self, part: &str) -> Option<usize> {
        self.names.iter().position(|n| n.contains(part))
    }
}

/// Whether `name` is one of the compiler's soft-float or conversion routines, or the
/// crate's own float-to-fixed conversion (counted to their callers as well).
fn is_float_routine(name: &str) -> bool {
    name.starts_with("compiler_builtins::float")
        || name.starts_with("__aeabi_f")
        || name.starts_with("__aeabi_i2f")
        || name.starts_with("__aeabi_ui2f")
        || matches!(name, "fminf" | "fmaxf")
        || name.contains("q24_bits_from_f32")
}

/// One function's share of the profile (instructions).
#[derive(Clone, Debug, PartialEq)]
pub struct Share {
    /// The function.
    pub name: String,
    /// In the costliest window.
    pub worst: u64,
    /// Mean over the windows, where it is counted (`None` in
    /// [`Report::float_by_caller`], which counts the costliest window only).
    pub mean: Option<f64>,
}

/// What [`ExecProfile::finish`] reports.
#[derive(Clone, Debug, PartialEq)]
pub struct Report {
    /// Windows closed.
    pub windows: u64,
    /// Mean instructions per window.
    pub mean: f64,
    /// Instructions of the costliest window.
    pub worst: u64,
    /// Its number among the windows (1-based).
    pub worst_window: u64,
    /// Per function, costliest first in the worst window.
    pub functions: Vec<Share>,
    /// Soft-float and conversion routines by the function that called them (the worst
    /// window's), costliest first.
    pub float_by_caller: Vec<Share>,
}

/// The profile being read (module docs).
#[derive(Debug)]
pub struct ExecProfile {
    symbols: Symbols,
    marker: usize,
    float_routine: Vec<bool>,
    block_len: HashMap<u32, u32>,
    /// A translation being read: its first address and instruction count.
    translating: Option<(Option<u32>, u32)>,
    window: Option<Window>,
    previous: Option<usize>,
    last_own: Option<usize>,
    windows: u64,
    total: u64,
    sum: Vec<u64>,
    worst: Option<Window>,
    worst_window: u64,
}

/// One window's counts.
#[derive(Clone, Debug)]
struct Window {
    caller: Option<usize>,
    total: u64,
    by_function: Vec<u64>,
    float_by_caller: Vec<u64>,
}

impl ExecProfile {
    /// A profile over `symbols`, one window per call of the function `marker` (an
    /// index of [`Symbols::find`]).
    pub fn new(symbols: Symbols, marker: usize) -> ExecProfile {
        let float_routine = (0..symbols.len()).map(|i| is_float_routine(symbols.name(i))).collect();
        let n = symbols.len();
        ExecProfile {
            symbols,
            marker,
            float_routine,
            block_len: HashMap::new(),
            translating: None,
            window: None,
            previous: None,
            last_own: None,
            windows: 0,
            total: 0,
            sum: vec![0; n],
            worst: None,
            worst_window: 0,
        }
    }

    /// Reads one line of QEMU's log.
    pub fn line(&mut self, line: &str) {
        if line.starts_with("IN:") {
            self.end_translation();
            self.translating = Some((None, 0));
            return;
        }
        if let Some((first, count)) = &mut self.translating {
            if let Some(a) = line
                .strip_prefix("0x")
                .and_then(|r| r.split(':').next())
                .and_then(|a| u32::from_str_radix(a, 16).ok())
            {
                first.get_or_insert(a);
                *count += 1;
                return;
            }
            self.end_translation();
        }
        if let Some(pc) = line.strip_prefix("Trace ").and_then(executed_pc) {
            self.executed(pc);
        }
    }

    fn end_translation(&mut self) {
        if let Some((Some(first), count)) = self.translating.take() {
            let len = self.block_len.entry(first).or_insert(0);
            *len = (*len).max(count);
        }
    }

    fn executed(&mut self, pc: u32) {
        let n = u64::from(self.block_len.get(&pc).copied().unwrap_or(1));
        let function = self.symbols.index_of(pc);
        if function == Some(self.marker) && self.window.is_none() {
            let len = self.symbols.len();
            self.window = Some(Window {
                caller: self.previous,
                total: 0,
                by_function: vec![0; len],
                float_by_caller: vec![0; len],
            });
        } else if let Some(w) = &self.window
            && function.is_some()
            && function == w.caller
        {
            self.close_window();
        }
        if let (Some(w), Some(f)) = (&mut self.window, function) {
            w.total += n;
            if let Some(c) = w.by_function.get_mut(f) {
                *c += n;
            }
            if self.float_routine.get(f).copied().unwrap_or(false) {
                if let Some(c) = self.last_own.and_then(|o| w.float_by_caller.get_mut(o)) {
                    *c += n;
                }
            } else {
                self.last_own = Some(f);
            }
        }
        self.previous = function;
    }

    fn close_window(&mut self) {
        let Some(w) = self.window.take() else { return };
        self.windows += 1;
        self.total += w.total;
        for (s, c) in self.sum.iter_mut().zip(&w.by_function) {
            *s += c;
        }
        if self.worst.as_ref().is_none_or(|b| w.total > b.total) {
            self.worst_window = self.windows;
            self.worst = Some(w);
        }
    }

    /// The report; `None` when no window closed.
    pub fn finish(mut self) -> Option<Report> {
        self.end_translation();
        let worst = self.worst.take()?;
        let windows = self.windows;
        let ranked = |counts: &[u64], means: Option<&[u64]>| -> Vec<Share> {
            let mut v: Vec<Share> = counts
                .iter()
                .enumerate()
                .filter(|(_, c)| **c > 0)
                .map(|(i, &c)| Share {
                    name: self.symbols.name(i).to_owned(),
                    worst: c,
                    mean: means.and_then(|m| m.get(i)).map(|&s| s as f64 / windows as f64),
                })
                .collect();
            v.sort_by_key(|s| std::cmp::Reverse(s.worst));
            v
        };
        Some(Report {
            windows,
            mean: self.total as f64 / windows as f64,
            worst: worst.total,
            worst_window: self.worst_window,
            functions: ranked(&worst.by_function, Some(&self.sum)),
            float_by_caller: ranked(&worst.float_by_caller, None),
        })
    }
}

/// The guest pc of an exec line's `[cs_base/pc/flags/cflags]`.
fn executed_pc(rest: &str) -> Option<u32> {
    let fields = rest.split('[').nth(1)?;
    let pc = fields.split('/').nth(1)?;
    u32::from_str_radix(pc, 16).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    const NM: &str = "00000100 T caller\n00000201 T marker\n00000300 T work\n00000400 T __aeabi_fmul\n\
                      00000500 t done\n20000000 B buffer\n";

    fn block(profile: &mut ExecProfile, first: u32, count: u32) {
        profile.line("IN: whatever");
        for k in 0..count {
            profile.line(&format!("0x{:08x}:  4770      bx lr", first + 2 * k));
        }
        profile.line("");
    }

    fn run(profile: &mut ExecProfile, pcs: &[u32]) {
        for pc in pcs {
            profile.line(&format!("Trace 0: 0x7f0000000000 [00000000/{pc:08x}/01000000/ff200000] sym"));
        }
    }

    #[test]
    fn symbols_are_the_code_ones_sorted_with_the_thumb_bit_cleared() {
        let s = Symbols::from_nm(NM);
        assert_eq!(s.len(), 5);
        assert_eq!(s.index_of(0x200).map(|i| s.name(i)), Some("marker"));
        assert_eq!(s.index_of(0x2ff).map(|i| s.name(i)), Some("marker"));
        assert_eq!(s.index_of(0x0ff), None);
        assert_eq!(s.find("work"), Some(2));
    }

    #[test]
    fn windows_count_each_block_by_its_longest_translation() {
        let symbols = Symbols::from_nm(NM);
        let marker = symbols.find("marker").expect("marker");
        let mut p = ExecProfile::new(symbols, marker);
        block(&mut p, 0x100, 3);
        block(&mut p, 0x200, 2);
        block(&mut p, 0x300, 5);
        block(&mut p, 0x300, 1); // a shorter translation of the same block
        block(&mut p, 0x400, 7);
        // caller, [marker, work, fmul, work], caller, [marker, work], caller
        run(&mut p, &[0x100, 0x200, 0x300, 0x400, 0x300, 0x100, 0x200, 0x300, 0x100]);
        let r = p.finish().expect("two windows");
        assert_eq!(r.windows, 2);
        // The first window: 2 + 5 + 7 + 5, the second 2 + 5.
        assert_eq!(r.worst, 19);
        assert_eq!(r.worst_window, 1);
        assert!((r.mean - 13.0).abs() < 1e-12);
        let work = r.functions.iter().find(|s| s.name == "work").expect("work");
        assert_eq!(work.worst, 10);
        assert!(work.mean.is_some_and(|m| (m - 7.5).abs() < 1e-12));
        assert_eq!(r.float_by_caller, vec![Share { name: "work".into(), worst: 7, mean: None }]);
    }

    #[test]
    fn no_window_no_report() {
        let symbols = Symbols::from_nm(NM);
        let p = ExecProfile::new(symbols, 1);
        assert_eq!(p.finish(), None);
    }
}
