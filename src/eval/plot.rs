//! PNG plots and contact sheets for `conifer eval` and `conifer bench`
//! (plotters' bitmap backend; text in the Fira Mono font Bevy embeds).

use image::{Rgb, RgbImage, RgbaImage};
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::Once;

/// Why a plot could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// Drawing failed.
    #[error("drawing failed: {0}")]
    Draw(String),
    /// Writing the PNG failed.
    #[error("{path}: {source}")]
    Write {
        /// The file.
        path: String,
        /// The cause.
        source: image::ImageError,
    },
}

fn draw_error(e: impl std::fmt::Display) -> PlotError {
    PlotError::Draw(e.to_string())
}

const FONT: &str = "sans-serif";

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // Bevy's embedded Fira Mono subset (ASCII): no system fonts needed.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, bevy::text::DEFAULT_FONT_DATA);
    });
}

fn save(buffer: Vec<u8>, width: u32, height: u32, path: &Path) -> Result<(), PlotError> {
    let image = RgbImage::from_raw(width, height, buffer).ok_or_else(|| PlotError::Draw("buffer size".into()))?;
    image.save(path).map_err(|source| PlotError::Write {
        path: path.display().to_string(),
        source,
    })
}

/// One named series of points.
pub struct Series {
    /// Legend label.
    pub name: String,
    /// Points `(x, y)`; non-finite or (on a log axis) non-positive ones are skipped.
    pub points: Vec<(f64, f64)>,
}

/// Axes of a [`line_plot`].
pub struct Axes<'a> {
    /// Title above the plot.
    pub title: &'a str,
    /// Label of the x axis.
    pub x_label: &'a str,
    /// Label of the y axis.
    pub y_label: &'a str,
    /// Logarithmic x axis.
    pub log_x: bool,
    /// Logarithmic y axis.
    pub log_y: bool,
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(200, 60, 40),
    RGBColor(30, 110, 200),
    RGBColor(40, 150, 60),
    RGBColor(150, 80, 180),
    RGBColor(230, 150, 20),
    RGBColor(90, 90, 90),
];

/// A line plot of `series` (with markers) written to `path` as a PNG of
/// `width × height`.
pub fn line_plot(path: &Path, axes: &Axes, series: &[Series], width: u32, height: u32) -> Result<(), PlotError> {
    register_font();
    let usable =
        |x: f64, y: f64| x.is_finite() && y.is_finite() && (!axes.log_x || x > 0.0) && (!axes.log_y || y > 0.0);
    let points: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|&(x, y)| usable(x, y))
        .collect();
    let range = |values: Vec<f64>, log: bool| -> (f64, f64) {
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if !lo.is_finite() {
            return if log { (1.0, 10.0) } else { (0.0, 1.0) };
        }
        if log {
            (lo / 1.5, hi * 1.5)
        } else {
            let pad = ((hi - lo) * 0.08).max(1e-9);
            ((lo - pad).min(0.0f64.max(lo - pad)), hi + pad)
        }
    };
    let (x0, x1) = range(points.iter().map(|p| p.0).collect(), axes.log_x);
    let (y0, y1) = range(points.iter().map(|p| p.1).collect(), axes.log_y);
    let mut buffer = vec![255u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_error)?;
        macro_rules! draw {
            ($chart:expr) => {{
                let mut chart = $chart;
                chart
                    .configure_mesh()
                    .x_labels(6)
                    .y_labels(8)
                    .x_desc(axes.x_label)
                    .y_desc(axes.y_label)
                    .label_style((FONT, 14))
                    .draw()
                    .map_err(draw_error)?;
                for (k, s) in series.iter().enumerate() {
                    let color = PALETTE[k % PALETTE.len()];
                    let pts: Vec<(f64, f64)> = s.points.iter().copied().filter(|&(x, y)| usable(x, y)).collect();
                    chart
                        .draw_series(LineSeries::new(pts.clone(), color.stroke_width(2)))
                        .map_err(draw_error)?
                        .label(s.name.as_str())
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2)));
                    chart
                        .draw_series(pts.into_iter().map(|p| Circle::new(p, 3, color.filled())))
                        .map_err(draw_error)?;
                }
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperLeft)
                    .label_font((FONT, 14))
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .draw()
                    .map_err(draw_error)?;
            }};
        }
        let mut builder = ChartBuilder::on(&root);
        builder
            .caption(axes.title, (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70);
        match (axes.log_x, axes.log_y) {
            (false, false) => draw!(builder.build_cartesian_2d(x0..x1, y0..y1).map_err(draw_error)?),
            (true, false) => draw!(
                builder
                    .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
                    .map_err(draw_error)?
            ),
            (false, true) => draw!(
                builder
                    .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
                    .map_err(draw_error)?
            ),
            (true, true) => draw!(
                builder
                    .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
                    .map_err(draw_error)?
            ),
        }
        root.present().map_err(draw_error)?;
    }
    save(buffer, width, height, path)
}

/// A grid of pictures with column titles and row labels, written to
/// `path`: `cells[row][column]`, each scaled (nearest neighbour) to
/// `cell × cell` pixels, RGBA composited over white.
pub fn contact_sheet(
    path: &Path,
    columns: &[String],
    rows: &[String],
    cells: &[Vec<RgbaImage>],
    cell: u32,
) -> Result<(), PlotError> {
    register_font();
    let (left, top, gap) = (90u32, 28u32, 4u32);
    let ncols = columns.len() as u32;
    let nrows = rows.len() as u32;
    let width = left + ncols * (cell + gap);
    let height = top + nrows * (cell + gap);
    let mut sheet = RgbImage::from_pixel(width, height, Rgb([255, 255, 255]));
    for (r, row) in cells.iter().enumerate() {
        for (c, picture) in row.iter().enumerate() {
            if picture.width() == 0 || picture.height() == 0 {
                continue;
            }
            let x0 = left + c as u32 * (cell + gap);
            let y0 = top + r as u32 * (cell + gap);
            let scale = (cell as f32 / picture.width() as f32).min(cell as f32 / picture.height() as f32);
            let (w, h) = (
                (picture.width() as f32 * scale) as u32,
                (picture.height() as f32 * scale) as u32,
            );
            let (ox, oy) = ((cell - w.min(cell)) / 2, (cell - h.min(cell)) / 2);
            for y in 0..h.min(cell) {
                for x in 0..w.min(cell) {
                    let sx = ((x as f32 + 0.5) / scale) as u32;
                    let sy = ((y as f32 + 0.5) / scale) as u32;
                    let p = picture
                        .get_pixel(sx.min(picture.width() - 1), sy.min(picture.height() - 1))
                        .0;
                    sheet.put_pixel(x0 + ox + x, y0 + oy + y, Rgb([p[0], p[1], p[2]]));
                }
            }
        }
    }
    let mut buffer = sheet.into_raw();
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        let style = TextStyle::from((FONT, 15).into_font()).color(&BLACK);
        for (c, name) in columns.iter().enumerate() {
            let x = (left + c as u32 * (cell + gap) + 4) as i32;
            root.draw_text(name, &style, (x, 6)).map_err(draw_error)?;
        }
        for (r, name) in rows.iter().enumerate() {
            let y = (top + r as u32 * (cell + gap) + cell / 2) as i32 - 8;
            root.draw_text(name, &style, (6, y)).map_err(draw_error)?;
        }
        root.present().map_err(draw_error)?;
    }
    save(buffer, width, height, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plots_and_sheets_are_written_with_ink() {
        let dir = tempfile::tempdir().unwrap();
        let plot = dir.path().join("plot.png");
        line_plot(
            &plot,
            &Axes {
                title: "error vs distance",
                x_label: "distance (m)",
                y_label: "error",
                log_x: true,
                log_y: false,
            },
            &[Series {
                name: "ours".into(),
                points: vec![(10.0, 0.1), (100.0, 0.05), (f64::NAN, 1.0), (-1.0, 2.0)],
            }],
            480,
            320,
        )
        .unwrap();
        let image = image::open(&plot).unwrap().to_rgb8();
        assert_eq!(image.dimensions(), (480, 320));
        let inked = image.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert!(inked > 1000, "{inked} non-white pixels");

        let sheet = dir.path().join("sheet.png");
        let red = RgbaImage::from_pixel(8, 8, image::Rgba([255, 0, 0, 255]));
        contact_sheet(
            &sheet,
            &["a".into(), "b".into()],
            &["1 m".into()],
            &[vec![red.clone(), red]],
            32,
        )
        .unwrap();
        let image = image::open(&sheet).unwrap().to_rgb8();
        let red_pixels = image.pixels().filter(|p| p.0 == [255, 0, 0]).count();
        assert_eq!(red_pixels, 2 * 32 * 32);
    }
}
