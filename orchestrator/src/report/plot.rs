//! Charts for dataset statistics and evaluation (PNG, plotters with an embedded font).

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

const W: u32 = 1000;
const H: u32 = 560;
const BLUE: RGBColor = RGBColor(52, 101, 164);
const PALETTE: [RGBColor; 7] = [
    RGBColor(52, 101, 164),
    RGBColor(204, 85, 0),
    RGBColor(78, 154, 6),
    RGBColor(117, 80, 123),
    RGBColor(193, 125, 17),
    RGBColor(164, 0, 0),
    RGBColor(85, 87, 83),
];

/// Height of one line of a bar group's name, in pixels.
const LABEL_LINE_PX: i32 = 18;

/// Splits a label into lines that `fits`, breaking before a `+` or after a space
/// ("RGB+Semantic+Both" → "RGB+Semantic", "+Both"); a part that fits nowhere gets a line alone.
fn wrap_label(label: &str, fits: impl Fn(&str) -> bool) -> Vec<String> {
    let mut parts: Vec<&str> = Vec::new();
    let mut start = 0;
    for (i, c) in label.char_indices() {
        let end = if c == '+' && i > 0 {
            i
        } else if c == ' ' {
            i + 1
        } else {
            continue;
        };
        if end > start {
            parts.push(&label[start..end]);
            start = end;
        }
    }
    parts.push(&label[start..]);
    let mut lines: Vec<String> = Vec::new();
    for part in parts.into_iter().filter(|p| !p.is_empty()) {
        match lines.last_mut() {
            Some(line) if fits(&format!("{line}{part}").trim_end()) => line.push_str(part),
            _ => lines.push(part.to_string()),
        }
    }
    lines.into_iter().map(|l| l.trim_end().to_string()).collect()
}

/// The series' legend in the charts' one style, at `at`.
fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    at: SeriesLabelPosition,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .position(at)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
        .map_err(err)
}

fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow::anyhow!("drawing chart: {e}")
}

/// Vertical bars with value labels.
pub fn bars(path: &Path, title: &str, y_label: &str, data: &[(String, f64)]) -> anyhow::Result<()> {
    super::fonts::ensure();
    let root = BitMapBackend::new(path, (W, H)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let max = data.iter().map(|d| d.1).fold(1.0, f64::max) * 1.15;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 26))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d((0..data.len()).into_segmented(), 0.0..max)
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .y_desc(y_label)
        .x_labels(data.len())
        .x_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) => data.get(*i).map(|d| d.0.clone()).unwrap_or_default(),
            _ => String::new(),
        })
        .label_style(("sans-serif", 16))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(data.iter().enumerate().map(|(i, d)| {
            Rectangle::new([(SegmentValue::Exact(i), 0.0), (SegmentValue::Exact(i + 1), d.1)], BLUE.filled()).into_dyn()
        }))
        .map_err(err)?;
    chart
        .draw_series(data.iter().enumerate().map(|(i, d)| {
            Text::new(
                format!("{}", d.1 as u64),
                (SegmentValue::CenterOf(i), d.1 + max * 0.02),
                ("sans-serif", 15).into_font(),
            )
        }))
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Horizontal bars (many categories).
pub fn hbars(path: &Path, title: &str, x_label: &str, data: &[(String, f64)]) -> anyhow::Result<()> {
    super::fonts::ensure();
    let h = (80 + data.len() as u32 * 22).max(300);
    let root = BitMapBackend::new(path, (W, h)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let max = data.iter().map(|d| d.1).fold(1.0, f64::max) * 1.12;
    let n = data.len();
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 26))
        .margin(20)
        .x_label_area_size(40)
        .y_label_area_size(160)
        .build_cartesian_2d(0.0..max, (0..n).into_segmented())
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_y_mesh()
        .x_desc(x_label)
        .y_labels(n)
        .y_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) => data.get(n - 1 - *i).map(|d| d.0.clone()).unwrap_or_default(),
            _ => String::new(),
        })
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    chart
        .draw_series(data.iter().enumerate().map(|(i, d)| {
            let row = n - 1 - i;
            let mut r =
                Rectangle::new([(0.0, SegmentValue::Exact(row)), (d.1, SegmentValue::Exact(row + 1))], BLUE.filled());
            r.set_margin(2, 2, 0, 0);
            r
        }))
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Histogram with a fixed bin width and the mean marked.
pub fn histogram(path: &Path, title: &str, x_label: &str, values: &[f64], bin: f64) -> anyhow::Result<()> {
    super::fonts::ensure();
    let root = BitMapBackend::new(path, (W, H)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let hi = values.iter().copied().fold(bin, f64::max);
    let nbins = (hi / bin).ceil() as usize + 1;
    let mut counts = vec![0u64; nbins];
    for v in values {
        counts[((v / bin) as usize).min(nbins - 1)] += 1;
    }
    let max = counts.iter().copied().max().unwrap_or(1) as f64 * 1.12;
    let mean = values.iter().sum::<f64>() / values.len().max(1) as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 26))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..nbins as f64 * bin, 0.0..max)
        .map_err(err)?;
    chart.configure_mesh().x_desc(x_label).y_desc("programs").label_style(("sans-serif", 16)).draw().map_err(err)?;
    chart
        .draw_series(counts.iter().enumerate().map(|(i, c)| {
            Rectangle::new([(i as f64 * bin, 0.0), ((i + 1) as f64 * bin, *c as f64)], BLUE.mix(0.85).filled())
        }))
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(PathElement::new(vec![(mean, 0.0), (mean, max)], RED.stroke_width(2))))
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(Text::new(
            format!("mean {mean:.2} m"),
            (mean + bin * 0.3, max * 0.92),
            ("sans-serif", 18).into_font(),
        )))
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// A named series of (x, y) points.
pub type Series = (String, Vec<(f64, f64)>);

/// Line chart of several series over a shared x axis.
pub fn lines(path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series]) -> anyhow::Result<()> {
    let groups: Vec<LineGroup> = series.iter().map(|(name, s)| (name.clone(), vec![s.clone()])).collect();
    grouped_lines(path, title, x_label, y_label, &groups)
}

/// A named group of series drawn in one colour (e.g. a method's seeds).
pub type LineGroup = (String, Vec<Vec<(f64, f64)>>);

/// Line chart of groups of series over a shared x axis: one colour and one legend entry per
/// group; a group's members are told apart by their line: solid, dashed, dotted, in order.
pub fn grouped_lines(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    groups: &[LineGroup],
) -> anyhow::Result<()> {
    super::fonts::ensure();
    // the legend has a panel of its own, right of the chart: over the lines it hid them
    let root = BitMapBackend::new(path, (W + LEGEND_PX, H)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let (plot, panel) = root.split_horizontally(W);
    let pts = groups.iter().flat_map(|g| g.1.iter().flatten());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    let pad = ((y1 - y0) * 0.08).max(1e-3);
    let mut chart = ChartBuilder::on(&plot)
        .caption(title, ("sans-serif", 22))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1.max(x0 + 1e-9), (y0 - pad)..(y1 + pad))
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&|v| short_count(*v))
        .label_style(("sans-serif", 16))
        .draw()
        .map_err(err)?;
    let font: TextStyle = ("sans-serif", 15).into_font().into();
    for (i, (name, members)) in groups.iter().enumerate() {
        let style = PALETTE[i % PALETTE.len()].stroke_width(2);
        for (k, s) in members.iter().enumerate() {
            let pts = s.iter().copied();
            match k % 3 {
                0 => chart.draw_series(LineSeries::new(pts, style)),
                1 => chart.draw_series(DashedLineSeries::new(pts, 10, 6, style)),
                _ => chart.draw_series(DashedLineSeries::new(pts, 3, 5, style)),
            }
            .map_err(err)?;
        }
        let y = 70 + i as i32 * 24;
        panel.draw(&PathElement::new(vec![(8, y), (34, y)], style.stroke_width(3))).map_err(err)?;
        panel.draw(&Text::new(name.clone(), (42, y), font.pos(Pos::new(HPos::Left, VPos::Center)))).map_err(err)?;
    }
    root.present().map_err(err)?;
    Ok(())
}

/// Width of the legend's panel beside a line chart, in pixels.
const LEGEND_PX: u32 = 270;

/// An axis count in few characters: 250000 → "250k", 1500000 → "1.5M".
fn short_count(v: f64) -> String {
    let a = v.abs();
    let (x, unit) = if a >= 1e6 {
        (v / 1e6, "M")
    } else if a >= 1e3 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    let digits = if (x - x.round()).abs() < 1e-9 { 0 } else { 1 };
    format!("{x:.digits$}{unit}")
}

/// Groups of bars: one group per `groups` entry (a label and, per bucket, a value and a
/// half-width drawn as a whisker where it is above 0), one bar colour per bucket, named in the legend.
pub fn grouped_bars(
    path: &Path,
    title: &str,
    y_label: &str,
    buckets: &[&str],
    groups: &[(String, Vec<(f64, f64)>)],
) -> anyhow::Result<()> {
    super::fonts::ensure();
    let root = BitMapBackend::new(path, (W, H)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let nb = buckets.len();
    let (corner, max) = legend_corner(groups, nb);
    let slots = groups.len() * (nb + 1);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 26))
        .margin(20)
        .x_label_area_size(70)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..slots as f64, 0.0..max)
        .map_err(err)?;
    let plot_w = chart.plotting_area().dim_in_pixel().0;
    let group_px = (plot_w as f64 * (nb + 1) as f64 / slots as f64 - 6.0).max(1.0) as u32;
    let font: TextStyle = ("sans-serif", 16).into_font().into();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .y_desc(y_label)
        .x_labels(0)
        .label_style(("sans-serif", 16))
        .draw()
        .map_err(err)?;
    for (gi, (name, vals)) in groups.iter().enumerate() {
        let x0 = (gi * (nb + 1)) as f64;
        for (bi, &(m, e)) in vals.iter().enumerate() {
            let x = x0 + bi as f64;
            let c = PALETTE[bi % PALETTE.len()];
            chart
                .draw_series(std::iter::once(Rectangle::new([(x + 0.1, 0.0), (x + 0.9, m)], c.filled())))
                .map_err(err)?;
            if e <= 0.0 {
                continue;
            }
            let whisker = [
                PathElement::new(vec![(x + 0.5, (m - e).max(0.0)), (x + 0.5, m + e)], BLACK.stroke_width(2)),
                PathElement::new(vec![(x + 0.35, m + e), (x + 0.65, m + e)], BLACK.stroke_width(2)),
                PathElement::new(
                    vec![(x + 0.35, (m - e).max(0.0)), (x + 0.65, (m - e).max(0.0))],
                    BLACK.stroke_width(2),
                ),
            ];
            chart.draw_series(whisker).map_err(err)?;
        }
        // centred under the group's bars, on as many lines as the group's width needs
        let centre = x0 + nb as f64 / 2.0;
        let fits = |line: &str| root.estimate_text_size(line, &font).map_or(true, |(w, _)| w <= group_px);
        // in pixels on the whole image: the chart clamps points below its axis onto the axis
        let (px, axis) = chart.backend_coord(&(centre, 0.0));
        for (li, line) in wrap_label(name, fits).into_iter().enumerate() {
            let at = (px, axis + 6 + LABEL_LINE_PX * li as i32);
            root.draw(&Text::new(line, at, font.clone().pos(Pos::new(HPos::Center, VPos::Top)))).map_err(err)?;
        }
    }
    for (bi, b) in buckets.iter().enumerate() {
        let c = PALETTE[bi % PALETTE.len()];
        chart
            .draw_series(std::iter::once(Rectangle::new([(0.0, 0.0), (0.0, 0.0)], c.filled())))
            .map_err(err)?
            .label(b.to_string())
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], c.filled()));
    }
    legend(&mut chart, corner)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Height of a bar chart's plotting area, in pixels (of `H`, less the caption, margins and labels).
const BARS_PLOT_PX: f64 = 400.0;

/// Where grouped bars' legend of `buckets` entries goes and the top of the y axis that leaves it
/// room: the upper corner above the lower of the two end groups (the legend is about one group
/// wide), with the axis raised until that group's bars stay below it. In the middle right, its
/// old place, it covered the last group's bars.
fn legend_corner(groups: &[(String, Vec<(f64, f64)>)], buckets: usize) -> (SeriesLabelPosition, f64) {
    let top =
        |g: Option<&(String, Vec<(f64, f64)>)>| g.map_or(0.0, |g| g.1.iter().map(|(m, e)| m + e).fold(0.0, f64::max));
    let all = groups.iter().map(|g| top(Some(g))).fold(1.0, f64::max) * 1.15;
    let (first, last) = (top(groups.first()), top(groups.last()));
    let (corner, under) =
        if first <= last { (SeriesLabelPosition::UpperLeft, first) } else { (SeriesLabelPosition::UpperRight, last) };
    // a line of 20 px per entry, the border's padding and a gap above the bars
    let share = ((buckets as f64 * 20.0 + 40.0) / BARS_PLOT_PX).min(0.8);
    (corner, all.max(under / (1.0 - share)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_counts_are_short() {
        let got: Vec<String> = [0.0, 250.0, 250_000.0, 1_000_000.0, 1_500_000.0, 4_497_408.0].map(short_count).into();
        assert_eq!(got, ["0", "250", "250k", "1M", "1.5M", "4.5M"]);
    }

    #[test]
    fn the_bars_legend_sits_over_the_lower_end_group_with_room_above_it() {
        let group = |name: &str, sr: f64| (name.to_string(), vec![(sr, 1.0), (sr * 0.6, 1.0)]);
        // the study's sr_spl.png: +Both, last, among the tallest; Random, first, the lowest
        let study = [group("Random", 11.3), group("VisSem", 16.4), group("+Intervention", 34.4), group("+Both", 32.0)];
        let (corner, max) = legend_corner(&study, 2);
        assert!(matches!(corner, SeriesLabelPosition::UpperLeft));
        let legend_px = (max - 12.3) / max * BARS_PLOT_PX;
        assert!(legend_px >= 2.0 * 20.0 + 40.0, "Random's bars end {legend_px:.0} px below the top");
        assert!((max - 35.4 * 1.15).abs() < 1e-9, "no more headroom than the tallest bar's");

        let reversed: Vec<_> = study.iter().rev().cloned().collect();
        assert!(matches!(legend_corner(&reversed, 2).0, SeriesLabelPosition::UpperRight));
        let (_, max) = legend_corner(&[group("flat", 50.0)], 2);
        assert!(max >= 51.0 / (1.0 - 80.0 / BARS_PLOT_PX) - 1e-9, "one group: the axis makes room");
    }

    #[test]
    fn long_labels_break_before_a_plus_or_after_a_space() {
        let within = |n: usize| move |s: &str| s.chars().count() <= n;
        assert_eq!(wrap_label("RGB+Semantic+Both", within(12)), ["RGB+Semantic", "+Both"]);
        assert_eq!(wrap_label("Depth+Semantic+Both", within(10)), ["Depth", "+Semantic", "+Both"]);
        assert_eq!(wrap_label("Vision Only", within(8)), ["Vision", "Only"]);
        assert_eq!(wrap_label("+Intervention", within(5)), ["+Intervention"], "one part is never cut");
        assert_eq!(wrap_label("+Both", within(20)), ["+Both"]);
        for label in ["RGB+Semantic+Both", "Vision Only", "+Referencing"] {
            assert_eq!(wrap_label(label, within(3)).concat().replace(' ', ""), label.replace(' ', ""), "nothing lost");
        }
    }
}
