//! Resource use of this process, for the benches and the measuring examples.

/// User + system CPU time of this process so far (s, all threads), from `/proc/self/stat` at
/// 100 ticks per second (the kernel's USER_HZ on Linux); None where that file cannot be read
/// (off Linux) or parsed.
pub fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The fields after the command name, which is in parentheses and may contain spaces.
    let rest = stat.get(stat.rfind(')')? + 2..)?;
    let f: Vec<&str> = rest.split_whitespace().collect();
    // Fields 14 and 15 of the line (utime, stime) are 11 and 12 after the ')'.
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(target_os = "linux")]
    fn cpu_time_grows_with_work() {
        // Busy until the clock has moved 50 ms of CPU (at most 20 s of wall, for a loaded
        // machine): a reader that returned a constant never gets there.
        let a = super::cpu_seconds().expect("linux has /proc/self/stat");
        let t = std::time::Instant::now();
        let mut x = 0.0f64;
        let mut b = a;
        while b - a < 0.05 && t.elapsed().as_secs() < 20 {
            for _ in 0..100_000 {
                x += (x + 1.0).sqrt();
            }
            b = super::cpu_seconds().expect("linux has /proc/self/stat");
        }
        std::hint::black_box(x);
        assert!(b - a >= 0.05, "{a} -> {b} s of CPU in {:?}", t.elapsed());
    }
}
