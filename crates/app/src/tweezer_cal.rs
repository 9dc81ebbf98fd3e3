//! The plot of a trap calibration: the blocked spectrum of one axis and its
//! fitted model, log–log (PNG, plotters with an embedded font: no system
//! font lookup). Recording and fitting are `kilotouch_rig::tweezer::record`
//! and `kilotouch_rig::tweezer::calibration`.

use kilotouch_dsp::trap_psd::PsdFit;
use kilotouch_rig::tweezer::calibration::{TrapCalibration, TrapCalibrationSettings};
use kilotouch_rig::tweezer::record::model_name;
use kilotouch_rig::units::{to_pn_per_um, to_um_per_v};
use plotters::prelude::*;
use std::path::Path;

use crate::paper::style::FONT;

/// The one embedded font of every plot ([`crate::paper::style::ensure_font`]).
fn ensure_font() -> anyhow::Result<()> {
    crate::paper::style::ensure_font().map_err(anyhow::Error::msg)
}

/// Draw the blocked spectrum and the fitted model (log–log) to a PNG.
pub fn plot_fit(
    path: &Path,
    fit: &PsdFit,
    cal: &TrapCalibration,
    s: &TrapCalibrationSettings,
) -> anyhow::Result<()> {
    ensure_font()?;
    let spec = &fit.spectrum;
    let (f0, f1) = (
        spec.f.first().copied().unwrap_or(1.0),
        spec.f.last().copied().unwrap_or(10.0),
    );
    let model: Vec<(f64, f64)> = (0..=400)
        .map(|i| {
            let f = f0 * (f1 / f0).powf(i as f64 / 400.0);
            (f, fit.model_at(f))
        })
        .collect();
    let all = spec.p.iter().copied().chain(model.iter().map(|m| m.1));
    let (pmin, pmax) = all.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    if !(pmin.is_finite() && pmin > 0.0 && pmax > pmin) {
        anyhow::bail!("nothing to plot: the spectrum is not positive");
    }
    const W: u32 = 960;
    const H: u32 = 640;
    let mut buf = vec![255_u8; (W as usize) * (H as usize) * 3];
    draw_fit(
        &mut buf,
        (W, H),
        spec,
        &model,
        cal,
        s,
        (f0, f1),
        (pmin, pmax),
    )?;
    image::save_buffer(path, &buf, W, H, image::ExtendedColorType::Rgb8)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(())
}

/// The drawing of [`plot_fit`] into an RGB buffer.
#[allow(clippy::too_many_arguments)]
fn draw_fit(
    buf: &mut [u8],
    size: (u32, u32),
    spec: &kilotouch_dsp::trap_psd::BlockedSpectrum,
    model: &[(f64, f64)],
    cal: &TrapCalibration,
    s: &TrapCalibrationSettings,
    (f0, f1): (f64, f64),
    (pmin, pmax): (f64, f64),
) -> anyhow::Result<()> {
    let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
    root.fill(&WHITE)?;
    let title = format!(
        "κ = {:.3} ± {:.3} pN/µm   f_c = {:.1} ± {:.1} Hz   R_d = {:.4} µm/V",
        to_pn_per_um(cal.kappa_n_per_m),
        to_pn_per_um(cal.kappa_se_n_per_m),
        cal.corner_hz,
        cal.corner_se_hz,
        to_um_per_v(cal.rd_m_per_v)
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FONT, 22).into_font())
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(90)
        .build_cartesian_2d(
            ((f0 * 0.8)..(f1 * 1.25)).log_scale(),
            ((pmin * 0.5)..(pmax * 2.0)).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("frequency (Hz)")
        .y_desc("power spectral density (V²/Hz)")
        .label_style((FONT, 17))
        .axis_desc_style((FONT, 20))
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .draw()?;
    let blue = RGBColor(31, 119, 180);
    let red = RGBColor(214, 39, 40);
    chart
        .draw_series(
            spec.f
                .iter()
                .zip(&spec.p)
                .map(|(&f, &p)| Circle::new((f, p), 3, blue.filled())),
        )?
        .label(format!(
            "blocked periodogram ({} points per block)",
            spec.points_per_block
        ))
        .legend(move |(x, y)| Circle::new((x + 10, y), 4, blue.filled()));
    chart
        .draw_series(LineSeries::new(model.iter().copied(), red.stroke_width(3)))?
        .label(format!(
            "fit: {} (χ²/dof {:.2}, backing {:.0} %)",
            model_name(s),
            cal.chi2_per_dof,
            cal.backing_pct
        ))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], red.stroke_width(3)));
    chart
        .configure_series_labels()
        .label_font((FONT, 17))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerLeft)
        .draw()?;
    root.present()?;
    Ok(())
}
