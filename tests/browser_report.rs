//! Opens the compare report in headless Chromium: takes a screenshot, checks it is not blank
//! and that the page logged no console error. Needs Chromium: without one (and `CI` not `true`)
//! the build marks the test ignored and says so (tests/common/shared_data.rs); when it runs and
//! finds none it fails. `.ci/run` installs Debian's `chromium`.
//!
//! A control page that throws proves the console-error detection can fail.

#[path = "common/shared_data.rs"]
mod shared_data;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Runs headless Chromium on `html`, returns (screenshot PNG bytes, stderr log).
fn screenshot(browser: &Path, html: &Path, work: &Path) -> (Vec<u8>, String) {
    let png = work.join(format!(
        "{}.png",
        html.file_stem().unwrap().to_string_lossy()
    ));
    let profile = tempfile::tempdir().unwrap();
    let url = format!("file://{}", html.canonicalize().unwrap().display());
    let mut child = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1280,2000",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", png.display()))
        .arg(&url)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start chromium");
    let mut stderr = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut stderr, &mut s).ok();
        s
    });
    let start = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if start.elapsed() > Duration::from_secs(90) {
            child.kill().ok();
            child.wait().ok();
            panic!("chromium did not finish within 90 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let log = reader.join().unwrap();
    let bytes =
        std::fs::read(&png).unwrap_or_else(|e| panic!("no screenshot ({e}); chromium log:\n{log}"));
    (bytes, log)
}

/// Console errors the page itself produced (uncaught exceptions, console.error).
fn console_errors(log: &str) -> Vec<&str> {
    log.lines()
        .filter(|l| l.contains("Uncaught") || l.contains("ERROR:CONSOLE"))
        .collect()
}

/// Luminance variance and fraction of non-white pixels of a screenshot.
fn picture_stats(png: &[u8]) -> (f64, f64) {
    let img = image::load_from_memory(png).unwrap().to_rgb8();
    let n = (img.width() * img.height()) as f64;
    let lum: Vec<f64> = img
        .pixels()
        .map(|p| 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64)
        .collect();
    let mean = lum.iter().sum::<f64>() / n;
    let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n;
    let ink = lum.iter().filter(|&&l| l < 200.0).count() as f64 / n;
    (var, ink)
}

/// Loads a copy of `html` with a measuring script in a 1280 px wide headless Chromium and
/// returns, per table, the right edge of its visible box, and the page's scroll width.
fn table_extents(browser: &Path, html: &Path, work: &Path) -> (Vec<f64>, f64) {
    let page = std::fs::read_to_string(html).unwrap();
    let script = "<script>window.addEventListener('load',()=>{const r=[];\
        for(const t of document.querySelectorAll('table')){\
        const b=(t.parentElement.className==='tablebox'?t.parentElement:t).getBoundingClientRect();\
        r.push(b.right);}\
        const p=document.createElement('pre');p.id='measure';\
        p.textContent='MEASURE '+document.documentElement.scrollWidth+' '+r.join(' ');\
        document.body.appendChild(p);});</script>";
    let measured = work.join(format!(
        "measure_{}",
        html.file_name().unwrap().to_string_lossy()
    ));
    std::fs::write(
        &measured,
        page.replace("</body>", &format!("{script}</body>")),
    )
    .unwrap();
    let profile = tempfile::tempdir().unwrap();
    let o = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--hide-scrollbars",
            "--window-size=1280,2000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!(
            "file://{}",
            measured.canonicalize().unwrap().display()
        ))
        .output()
        .expect("start chromium");
    let dom = String::from_utf8_lossy(&o.stdout);
    let line = dom
        .lines()
        .find_map(|l| l.split("<pre id=\"measure\">MEASURE ").nth(1))
        .unwrap_or_else(|| panic!("no measurement in the dumped DOM of {}", html.display()));
    let line = line.split('<').next().unwrap();
    let v: Vec<f64> = line
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    (v[1..].to_vec(), v[0])
}

/// Every table of the compare, bonnets, spots and calibration reports fits a 1280 px window (a wide table scrolls
/// inside its own box); the spots tables were 1,840 and 2,200 px wide before.
#[test]
#[cfg_attr(
    no_chromium,
    ignore = "needs chromium: apt-get install chromium or set BONNETLAB_CHROMIUM (README, Tests)"
)]
fn report_tables_fit_a_1280_px_window() {
    let browser = shared_data::chromium();
    let dir = tempfile::tempdir().unwrap();
    let bin = env!("CARGO_BIN_EXE_bonnetlab");
    let run = |args: &[&std::ffi::OsStr]| {
        let o = Command::new(bin).args(args).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    let d = dir.path();
    let (samples, compare, spots_in, spots_out) = (
        d.join("samples"),
        d.join("compare"),
        d.join("spots_in"),
        d.join("spots_out"),
    );
    run(&[
        "demo".as_ref(),
        "--repeats".as_ref(),
        "1".as_ref(),
        "--generate-samples".as_ref(),
        samples.as_os_str(),
        "--out".as_ref(),
        compare.as_os_str(),
    ]);
    run(&[
        "spots".as_ref(),
        "--make-sample".as_ref(),
        spots_in.as_os_str(),
    ]);
    let manifest = spots_in.join("manifest.toml");
    run(&[
        "spots".as_ref(),
        manifest.as_os_str(),
        "--out".as_ref(),
        spots_out.as_os_str(),
    ]);
    // The calibration report (dwell writes no HTML report, only maps, CSV and plots).
    let calibration = d.join("calibration");
    let recipe = samples.join("original").join("recipe.toml");
    run(&[
        "calibrate".as_ref(),
        recipe.as_os_str(),
        "--out".as_ref(),
        calibration.as_os_str(),
    ]);
    for html in [
        compare.join("report.html"),
        compare.join("bonnets").join("report.html"),
        spots_out.join("report.html"),
        calibration.join("report.html"),
    ] {
        let (tables, page_w) = table_extents(&browser, &html, d);
        assert!(!tables.is_empty(), "{}: no table measured", html.display());
        assert!(
            page_w <= 1280.0,
            "{}: page {page_w} px wide",
            html.display()
        );
        for (k, right) in tables.iter().enumerate() {
            assert!(
                *right <= 1280.0,
                "{}: table {k} reaches {right} px in a 1280 px window",
                html.display()
            );
        }
    }
}

#[test]
#[cfg_attr(
    no_chromium,
    ignore = "needs chromium: apt-get install chromium or set BONNETLAB_CHROMIUM (README, Tests)"
)]
fn compare_report_renders_in_chromium_without_console_errors() {
    let browser = shared_data::chromium();
    let dir = tempfile::tempdir().unwrap();
    let samples = dir.path().join("samples");
    let report = dir.path().join("report");
    let o = Command::new(env!("CARGO_BIN_EXE_bonnetlab"))
        .args(["demo", "--repeats", "1", "--generate-samples"])
        .arg(&samples)
        .arg("--out")
        .arg(&report)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let html = report.join("report.html");

    // Control: a page that throws must be caught by the console check.
    let bad = dir.path().join("bad.html");
    std::fs::write(&bad, "<!DOCTYPE html><html><body><p>x</p><script>throw new Error('boom-control')</script></body></html>")
        .unwrap();
    let (_, bad_log) = screenshot(&browser, &bad, dir.path());
    assert!(
        !console_errors(&bad_log).is_empty(),
        "the console check misses a thrown error; log:\n{bad_log}"
    );

    // The bonnet comparison (recipe runs) renders without console errors too.
    let (_, blog) = screenshot(
        &browser,
        &report.join("bonnets").join("report.html"),
        dir.path(),
    );
    let berrors = console_errors(&blog);
    assert!(
        berrors.is_empty(),
        "console errors from the bonnets report:\n{}",
        berrors.join("\n")
    );

    let (png, log) = screenshot(&browser, &html, dir.path());
    let errors = console_errors(&log);
    assert!(
        errors.is_empty(),
        "console errors from the report:\n{}",
        errors.join("\n")
    );
    let (var, ink) = picture_stats(&png);
    // A blank (all white) page has variance 0 and no ink; the report's maps and tables give
    // both in quantity.
    assert!(
        var > 500.0,
        "screenshot looks blank: luminance variance {var:.1}"
    );
    assert!(
        ink > 0.05,
        "screenshot looks blank: only {:.1} % dark pixels",
        100.0 * ink
    );
    let img = image::load_from_memory(&png).unwrap();
    assert_eq!(img.width(), 1280);
}
