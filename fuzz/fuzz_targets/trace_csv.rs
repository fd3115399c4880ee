//! The trace CSV reader fed arbitrary bytes. Contract: no panic; an accepted trace has
//! at least two rows, every value finite and a strictly increasing time.
#![no_main]

use dcfo_host::trace::InputTrace;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(trace) = InputTrace::from_reader(data, "<fuzz>") {
        let rows = trace.rows();
        assert!(rows.len() >= 2);
        for w in rows.windows(2) {
            assert!(w[1].t > w[0].t);
        }
        for r in rows {
            for v in [r.t, r.u_alpha, r.u_beta, r.i_alpha, r.i_beta] {
                assert!(v.is_finite());
            }
        }
        assert!(trace.sample_period_s().is_finite() && trace.sample_period_s() > 0.0);
    }
});
