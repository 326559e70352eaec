//! `report.html` in a real browser: headless Chromium renders the page of a
//! small comparison with snapshots; its screenshot must not be blank and the
//! rendered page must hold the title, the table and every picture.
//!
//! A custom harness (libtest-mimic) looks for Chromium first: without one
//! (`apt-get install chromium`) the test is reported as ignored, with the
//! reason, never as passed; with `CI=true` or `LIPAC_REQUIRE_BROWSER=1` a
//! missing browser is a failure. `LIPAC_CHROMIUM` names the binary if it is
//! not on `PATH`.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode, Stdio};

use libtest_mimic::{Arguments, Trial};
use std::time::{Duration, Instant};

use lipac_sim::compare::{run_choice_with_snapshots, CompareConfig, SceneChoice};
use lipac_sim::report::{write_report_with_snapshots, PLOTS};
use lipac_sim::strategy::StrategyKind;

fn required() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true" || v == "1")
        || std::env::var("LIPAC_REQUIRE_BROWSER").is_ok_and(|v| v == "1")
}

fn chromium() -> Option<PathBuf> {
    let names: Vec<String> = match std::env::var("LIPAC_CHROMIUM") {
        Ok(c) => vec![c],
        Err(_) => ["chromium", "chromium-browser", "google-chrome"]
            .map(String::from)
            .to_vec(),
    };
    names.into_iter().map(PathBuf::from).find(|c| {
        Command::new(c)
            .arg("--version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    })
}

/// Runs headless Chromium with `args` and the page, within a minute;
/// returns its stdout.
fn headless(browser: &Path, profile: &Path, args: &[String], page: &str) -> String {
    let out_file = profile.join(format!("stdout-{}.txt", args.len()));
    let mut child = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--no-first-run",
            "--disable-dev-shm-usage",
            "--allow-file-access-from-files",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(args)
        .arg(page)
        .stdout(std::fs::File::create(&out_file).unwrap())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting chromium");
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "chromium failed: {status}");
            break;
        }
        if start.elapsed() > Duration::from_secs(90) {
            let _ = child.kill();
            panic!("chromium took over 90 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    std::fs::read_to_string(&out_file).unwrap()
}

fn main() -> ExitCode {
    let args = Arguments::from_args();
    let browser = chromium();
    let name = "report_html_renders_in_headless_chromium";
    let trial = match browser {
        Some(b) => Trial::test(name, move || {
            report_html_renders_in_headless_chromium(&b);
            Ok(())
        }),
        None if required() => Trial::test(name, || {
            Err("chromium missing (apt-get install chromium); CI=true or \
                 LIPAC_REQUIRE_BROWSER=1 requires it"
                .into())
        }),
        None => Trial::test(name, || Ok(())).with_ignored_flag(true),
    };
    let ignored = trial.has_ignored_flag();
    let conclusion = libtest_mimic::run(&args, vec![trial]);
    if ignored && conclusion.num_ignored > 0 && !args.list {
        println!(
            "not run: {name}: no chromium (apt-get install chromium, or LIPAC_CHROMIUM=binary)"
        );
    }
    conclusion.exit_code()
}

fn report_html_renders_in_headless_chromium(browser: &Path) {
    let config = CompareConfig {
        frames: Some(4),
        width: 48,
        height: 27,
        strategies: vec![
            StrategyKind::Full,
            StrategyKind::Frustum,
            StrategyKind::Lipac,
        ],
        share_ground_truth: true,
        threads: 2,
        adaptive_levels: None,
        lipac_cell_size: None,
        lipac_rise_shift: None,
        lipac_start: lipac_sim::compare::LipacStart::Default,
        lipac_warm_start_at_cuts: false,
        lipac_warm_start_hold: None,
    };
    let (r, snaps) =
        run_choice_with_snapshots(SceneChoice::Small, None, &config, &[0, 3], &mut |_, _| {})
            .unwrap();
    let dir = std::env::temp_dir().join(format!("lipac-html-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    write_report_with_snapshots(&r, &snaps, &dir).unwrap();
    let page = format!("file://{}", dir.join("report.html").display());
    let profile = dir.join("chromium-profile");
    std::fs::create_dir_all(&profile).unwrap();

    // The page as the browser built it: title, headline, table, pictures.
    let dom = headless(browser, &profile, &["--dump-dom".into()], &page);
    let title = "lipac: culling strategies compared on small";
    assert!(
        dom.contains(&format!("<title>{title}</title>")),
        "{dom:.400}"
    );
    assert!(dom.contains(&format!("<h1>{title}</h1>")));
    assert!(dom.contains("LiPaC: "));
    assert_eq!(dom.matches("<tr>").count(), 1 + 3, "table rows");
    assert!(dom.contains("<h3>Frame 3</h3>"));
    // Ground truth + 3 × (image, heat map, TLAS map) per frame, the scale.
    let pictures = dom.matches("src=\"data:image/png;base64,").count();
    assert_eq!(pictures, 2 * (1 + 3 * 3) + 2, "embedded PNGs");
    assert_eq!(dom.matches("<svg").count(), PLOTS.len(), "inline plots");

    // The screenshot: decoded, sized as asked, and far from blank.
    let shot = dir.join("screenshot.png");
    headless(
        browser,
        &profile,
        &[
            format!("--screenshot={}", shot.display()),
            "--window-size=1280,2400".into(),
        ],
        &page,
    );
    let mut decoder = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(&shot).expect("no screenshot written"),
    ));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (1280, 2400));
    let channels = info.color_type.samples();
    assert!(channels >= 3, "{:?}", info.color_type);
    let pixels: Vec<[u8; 3]> = buf[..info.buffer_size()]
        .chunks(channels)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let mut distinct: Vec<[u8; 3]> = pixels.clone();
    distinct.sort_unstable();
    distinct.dedup();
    // Text, plots, the rendered city and heat maps: many colours. A blank or
    // text-only page has a handful (antialiased grey).
    assert!(distinct.len() > 500, "{} distinct colours", distinct.len());
    let white = pixels.iter().filter(|p| **p == [255, 255, 255]).count();
    let dark = pixels.iter().filter(|p| p.iter().all(|&c| c < 40)).count();
    let n = pixels.len();
    assert!(white < n * 95 / 100, "{white} of {n} pixels white");
    // The heat maps of the full strategy are black: large dark areas.
    assert!(dark > n / 100, "{dark} of {n} pixels dark");
    let mean = pixels.iter().map(|p| f64::from(p[1])).sum::<f64>() / n as f64;
    let var = pixels
        .iter()
        .map(|p| (f64::from(p[1]) - mean).powi(2))
        .sum::<f64>()
        / n as f64;
    assert!(var > 500.0, "variance {var}");
    if std::env::var("LIPAC_KEEP_SCREENSHOT").is_ok() {
        eprintln!("screenshot kept in {}", shot.display());
    } else {
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
