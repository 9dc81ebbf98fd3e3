//! The desktop app (eframe + wgpu): shell, pages, microscope scene, live
//! plots. The real-time engine it drives is [`crate::engine`], which does
//! not depend on egui.
//!
//! `kilotouch` (no arguments) and `kilotouch gui` open it on the simulated
//! rig; `kilotouch gui --screenshot FILE.png --quit-after S` renders the
//! window for S seconds, saves a PNG and exits (non-zero if the image is
//! blank) — how CI checks the app and how the README images are made.

pub mod app;
pub mod charts;
pub mod env;
pub mod pages;
pub mod participant_screen;
pub mod path_field;
pub mod plot;
pub mod scene;
pub mod scene_wgpu;
pub mod settings;
pub mod work;

pub use app::{AppOptions, KilotouchApp};
pub use env::{AppliedCalibration, PageEnv, ShellRequest};
pub use settings::Page;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicI32;

/// `kilotouch gui` arguments.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct GuiArgs {
    /// Page to open.
    #[arg(long, value_enum)]
    pub page: Option<Page>,
    /// Rig file (TOML); default: the one used last, else the built-in rig.
    #[arg(long, value_name = "FILE")]
    pub rig_config: Option<PathBuf>,
    /// The rig to connect at start: `sim` or `serial:PATH[,…]` (a DAQ or
    /// its emulator); default: the one used last, else the simulated rig.
    #[arg(long, value_name = "SPEC")]
    pub rig: Option<String>,
    /// The tweezer to connect at start: `sim` or `serial:PATH[,…]` (a live
    /// tweezer or its emulator); default: the one used last, else the
    /// simulated tweezer.
    #[arg(long, value_name = "SPEC")]
    pub tweezer: Option<String>,
    /// Save a PNG of the window after --quit-after seconds, then exit
    /// (exit status 1 if the image is blank). Uses fresh settings.
    #[arg(long, value_name = "FILE.png", requires = "quit_after")]
    pub screenshot: Option<PathBuf>,
    /// Quit after this many seconds.
    #[arg(long, value_name = "SECONDS")]
    pub quit_after: Option<f64>,
    /// Bits kept per colour channel in the screenshot (1–8; fewer = smaller
    /// PNG, e.g. 5 for the README images).
    #[arg(long, value_name = "BITS", default_value_t = 8, value_parser = clap::value_parser!(u8).range(1..=8))]
    pub screenshot_bits: u8,
    /// Study output folder for the Study and Results pages (the Results
    /// page opens it when it holds a study).
    #[arg(long, value_name = "DIR")]
    pub study_dir: Option<PathBuf>,
    /// Open a sitting of the next pending participant with the simulated
    /// participant in real time and start it (a dry run on the Study page,
    /// participant view inline; how the README's Study image is made).
    #[arg(long)]
    pub simulate_sitting: bool,
    /// Record and calibrate the simulated tweezer at start (the Rig page's
    /// Tweezer section; how its screenshot is made).
    #[arg(long)]
    pub calibrate_tweezer: bool,
    /// Window size in points, WxH (default 1100x700).
    #[arg(long, value_name = "WxH", default_value = "1100x700")]
    pub size: String,
}

impl GuiArgs {
    /// The arguments of a plain `kilotouch` (no command).
    pub fn default_args() -> Self {
        Self {
            size: "1100x700".into(),
            screenshot_bits: 8,
            ..Default::default()
        }
    }
}

fn parse_size(s: &str) -> anyhow::Result<[f32; 2]> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| anyhow::anyhow!("--size must be WxH, e.g. 1100x700, got `{s}`"))?;
    let w: f32 = w
        .trim()
        .parse()
        .map_err(|_| anyhow::anyhow!("bad width in --size `{s}`"))?;
    let h: f32 = h
        .trim()
        .parse()
        .map_err(|_| anyhow::anyhow!("bad height in --size `{s}`"))?;
    if !(w.is_finite()
        && h.is_finite()
        && (200.0..=8000.0).contains(&w)
        && (150.0..=8000.0).contains(&h))
    {
        anyhow::bail!("--size `{s}` out of range (200–8000 × 150–8000)");
    }
    Ok([w, h])
}

/// Open the app; returns the process exit code.
pub fn run(args: &GuiArgs) -> anyhow::Result<ExitCode> {
    let size = parse_size(&args.size)?;
    if let Some(q) = args.quit_after
        && !(q.is_finite() && q >= 0.0)
    {
        anyhow::bail!("--quit-after must be a finite number of seconds ≥ 0, got {q}");
    }
    let exit_code = Arc::new(AtomicI32::new(0));
    let shot = args.screenshot.is_some();
    let opts = AppOptions {
        page: args.page,
        rig_config: args.rig_config.clone(),
        fresh_settings: shot,
        study_dir: args.study_dir.clone(),
        simulate_sitting: args.simulate_sitting,
        calibrate_tweezer: args.calibrate_tweezer,
        rig: args.rig.clone(),
        tweezer: args.tweezer.clone(),
        ..Default::default()
    };
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("kilotouch")
            .with_inner_size(size)
            .with_min_inner_size([640.0, 420.0]),
        persist_window: !shot,
        ..Default::default()
    };
    let bits = args.screenshot_bits;
    let plan = args
        .quit_after
        .map(|q| (args.screenshot.clone(), q, exit_code.clone()));
    eframe::run_native(
        "kilotouch",
        native,
        Box::new(move |cc| {
            let mut app = KilotouchApp::new(opts, cc.storage, cc.wgpu_render_state.as_ref());
            if let Some((path, q, code)) = plan {
                app.screenshot = Some(app::ScreenshotPlan::new(path, q, code, bits));
            }
            Ok(Box::new(app))
        }),
    )
    .map_err(|e| {
        anyhow::anyhow!(
            "cannot open the GUI: {e}\n(no display? the headless commands work without one: kilotouch --help)"
        )
    })?;
    let code = exit_code.load(std::sync::atomic::Ordering::SeqCst);
    Ok(if code == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(u8::try_from(code).unwrap_or(1))
    })
}

/// Save an egui image as an RGB PNG (opaque window; best compression),
/// keeping the top `bits` (1–8) of each channel.
pub fn save_png(img: &egui::ColorImage, path: &Path, bits: u8) -> anyhow::Result<()> {
    let mask = 0xFFu8 << (8 - bits.clamp(1, 8));
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let [w, h] = img.size;
    let mut rgb = Vec::with_capacity(w * h * 3);
    for p in &img.pixels {
        let [r, g, b, _] = p.to_srgba_unmultiplied();
        rgb.extend_from_slice(&[r & mask, g & mask, b & mask]);
    }
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    PngEncoder::new_with_quality(file, CompressionType::Best, FilterType::Adaptive).write_image(
        &rgb,
        u32::try_from(w)?,
        u32::try_from(h)?,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(())
}

/// A screenshot is *blank* when it is (nearly) uniform: fewer than 16
/// distinct colours, or a luminance standard deviation below 2 (of 255).
pub fn image_is_blank(img: &egui::ColorImage) -> bool {
    let n = img.pixels.len();
    if n == 0 {
        return true;
    }
    let mut seen = std::collections::HashSet::new();
    let (mut s, mut s2) = (0f64, 0f64);
    for p in &img.pixels {
        if seen.len() < 64 {
            seen.insert(p.to_array());
        }
        let y = 0.2126 * f64::from(p.r()) + 0.7152 * f64::from(p.g()) + 0.0722 * f64::from(p.b());
        s += y;
        s2 += y * y;
    }
    let mean = s / n as f64;
    let var = (s2 / n as f64 - mean * mean).max(0.0);
    seen.len() < 16 || var.sqrt() < 2.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use egui::{Color32, ColorImage};

    #[test]
    fn blank_detection() {
        let blank = ColorImage::new([64, 48], vec![Color32::from_gray(30); 64 * 48]);
        assert!(image_is_blank(&blank));
        let mut px = vec![Color32::from_gray(30); 64 * 48];
        for (i, p) in px.iter_mut().enumerate() {
            if i % 7 == 0 {
                *p = Color32::from_rgb((i % 251) as u8, (i % 13) as u8 * 19, 200);
            }
        }
        let busy = ColorImage::new([64, 48], px);
        assert!(!image_is_blank(&busy));
        // A few stray pixels on a uniform image are still blank.
        let mut px = vec![Color32::from_gray(30); 64 * 48];
        px[5] = Color32::WHITE;
        assert!(image_is_blank(&ColorImage::new([64, 48], px)));
    }

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.png");
        let px: Vec<Color32> = (0..20 * 10)
            .map(|i| Color32::from_rgb(i as u8, 255 - i as u8, 7))
            .collect();
        save_png(&ColorImage::new([20, 10], px.clone()), &p, 8).unwrap();
        let back = image::open(&p).unwrap().to_rgba8();
        assert_eq!(back.dimensions(), (20, 10));
        // pixel (x 3, y 2) is index 2·20 + 3 = 43 → (43, 255 − 43, 7)
        assert_eq!(back.get_pixel(3, 2).0, [43, 212, 7, 255]);
        assert!(
            save_png(
                &ColorImage::new([1, 1], vec![Color32::RED]),
                Path::new("/nonexistent/dir/x.png"),
                8
            )
            .is_err()
        );
        // 5 bits: the low 3 bits of every channel are cleared.
        save_png(&ColorImage::new([20, 10], px), &p, 5).unwrap();
        let back = image::open(&p).unwrap().to_rgba8();
        assert_eq!(back.get_pixel(3, 2).0, [43 & 0xF8, 212 & 0xF8, 0, 255]);
    }

    #[test]
    fn size_parsing() {
        assert_eq!(parse_size("1100x700").unwrap(), [1100.0, 700.0]);
        assert!(parse_size("1100").is_err());
        assert!(parse_size("10x10").is_err());
        assert!(parse_size("nanxnan").is_err());
    }
}
