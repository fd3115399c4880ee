//! `dcfo`: the host command-line tool.
fn main() {
    println!("dcfo host tool: subcommands arrive with the simulated drive");
}
