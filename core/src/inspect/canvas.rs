//! An RGB canvas for the inspection pictures: pixels, rectangles, lines, circles and text
//! rendered with the Go font (BSD-3-clause, `core/assets/fonts/LICENSE`) through `ab_glyph`,
//! so a deviation map carries its numbers, not only its colours.

use std::sync::OnceLock;

use ab_glyph::{point, Font, FontRef, PxScale, ScaleFont};

static FONT_DATA: &[u8] = include_bytes!("../../assets/fonts/Go-Regular.ttf");

/// The embedded font (`None` only if the embedded file were corrupt; a unit test parses it).
fn font() -> Option<&'static FontRef<'static>> {
    static FONT: OnceLock<Option<FontRef<'static>>> = OnceLock::new();
    FONT.get_or_init(|| FontRef::try_from_slice(FONT_DATA).ok())
        .as_ref()
}

/// A piece of text drawn on a canvas and its box (pixels, top-left origin).
#[derive(Clone, Debug, PartialEq)]
pub struct Label {
    /// The text.
    pub text: String,
    /// Left edge.
    pub x: i64,
    /// Top edge.
    pub y: i64,
    /// Width.
    pub width: i64,
    /// Height (the font size).
    pub height: i64,
    /// Font size, px.
    pub size: f32,
    /// Ink colour.
    pub colour: [u8; 3],
}

/// Colours of a boxed label.
#[derive(Clone, Copy)]
pub(crate) struct BoxStyle {
    pub ink: [u8; 3],
    pub fill: [u8; 3],
    pub border: [u8; 3],
}

/// An RGB image being drawn, with the labels drawn on it.
pub(crate) struct Canvas {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
    pub labels: Vec<Label>,
}

impl Canvas {
    pub fn new(width: usize, height: usize, background: [u8; 3]) -> Canvas {
        let rgb = background.repeat(width * height);
        Canvas {
            width,
            height,
            rgb,
            labels: Vec::new(),
        }
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        (x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height)
            .then(|| (y as usize * self.width + x as usize) * 3)
    }

    pub fn put(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if let Some(i) = self.index(x, y) {
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }

    /// The pixel at (x, y), if inside.
    pub fn get(&self, x: i64, y: i64) -> Option<[u8; 3]> {
        self.index(x, y)
            .map(|i| [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]])
    }

    fn blend(&mut self, x: i64, y: i64, c: [u8; 3], alpha: f32) {
        if let Some(i) = self.index(x, y) {
            let a = alpha.clamp(0.0, 1.0);
            for (dst, src) in self.rgb[i..i + 3].iter_mut().zip(c) {
                *dst = (f32::from(*dst) * (1.0 - a) + f32::from(src) * a).round() as u8;
            }
        }
    }

    pub fn fill(&mut self, x: i64, y: i64, w: i64, h: i64, c: [u8; 3]) {
        for yy in y.max(0)..(y + h).min(self.height as i64) {
            for xx in x.max(0)..(x + w).min(self.width as i64) {
                self.put(xx, yy, c);
            }
        }
    }

    pub fn frame(&mut self, x: i64, y: i64, w: i64, h: i64, c: [u8; 3]) {
        self.fill(x, y, w, 1, c);
        self.fill(x, y + h - 1, w, 1, c);
        self.fill(x, y, 1, h, c);
        self.fill(x + w - 1, y, 1, h, c);
    }

    /// A line `width` pixels wide; `dash` > 0 draws dashes of that length.
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), c: [u8; 3], width: i64, dash: usize) {
        // Never more steps than the canvas could show (a far end point is no reason to work).
        let n =
            ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).clamp(1, self.most_steps());
        for s in 0..=n {
            if dash > 0 && (s / dash) % 2 == 1 {
                continue;
            }
            let t = s as f64 / n as f64;
            let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
            let (x, y) = (x.round() as i64, y.round() as i64);
            self.fill(x - (width - 1) / 2, y - (width - 1) / 2, width, width, c);
        }
    }

    pub fn circle(&mut self, centre: (f64, f64), r: f64, c: [u8; 3], width: i64) {
        let n = ((2.0 * std::f64::consts::PI * r).ceil() as usize).clamp(8, self.most_steps());
        for s in 0..n {
            let a = 2.0 * std::f64::consts::PI * s as f64 / n as f64;
            let (x, y) = (centre.0 + r * a.cos(), centre.1 + r * a.sin());
            self.fill(
                x.round() as i64 - (width - 1) / 2,
                y.round() as i64 - (width - 1) / 2,
                width,
                width,
                c,
            );
        }
    }

    /// The most steps a line or circle is drawn with: a few per pixel of the canvas's edge.
    fn most_steps(&self) -> usize {
        8 * (self.width + self.height).max(1)
    }

    /// Width in pixels of `text` at `size`.
    pub fn text_width(text: &str, size: f32) -> f64 {
        let Some(font) = font() else {
            return 0.0;
        };
        let scaled = font.as_scaled(PxScale::from(size));
        let mut w = 0.0;
        let mut last = None;
        for ch in text.chars() {
            let id = scaled.glyph_id(ch);
            if let Some(prev) = last {
                w += scaled.kern(prev, id);
            }
            w += scaled.h_advance(id);
            last = Some(id);
        }
        f64::from(w)
    }

    /// Draw `text` with its box's top-left corner at (x, y) and record it as a label.
    pub fn text(&mut self, x: f64, y: f64, size: f32, text: &str, c: [u8; 3]) -> Label {
        let label = Label {
            text: text.to_string(),
            x: x.round() as i64,
            y: y.round() as i64,
            width: Canvas::text_width(text, size).ceil() as i64,
            height: size.ceil() as i64,
            size,
            colour: c,
        };
        self.draw_text(label.x as f32, label.y as f32, size, text, c);
        self.labels.push(label.clone());
        label
    }

    fn draw_text(&mut self, x: f32, y: f32, size: f32, text: &str, c: [u8; 3]) {
        let Some(font) = font() else {
            return;
        };
        let scaled = font.as_scaled(PxScale::from(size));
        // The box is the font size tall; the baseline sits at the ascent scaled into it.
        let baseline = y + size * scaled.ascent() / (scaled.ascent() - scaled.descent());
        let mut caret = x;
        let mut last = None;
        for ch in text.chars() {
            let id = scaled.glyph_id(ch);
            if let Some(prev) = last {
                caret += scaled.kern(prev, id);
            }
            let glyph = id.with_scale_and_position(PxScale::from(size), point(caret, baseline));
            caret += scaled.h_advance(id);
            last = Some(id);
            if let Some(outline) = font.outline_glyph(glyph) {
                let b = outline.px_bounds();
                let (bx, by) = (b.min.x as i64, b.min.y as i64);
                outline.draw(|gx, gy, cov| {
                    self.blend(bx + i64::from(gx), by + i64::from(gy), c, cov);
                });
            }
        }
    }

    /// Text centred on `cx`.
    pub fn text_centred(&mut self, cx: f64, y: f64, size: f32, text: &str, c: [u8; 3]) -> Label {
        let w = Canvas::text_width(text, size);
        self.text(cx - w / 2.0, y, size, text, c)
    }

    /// Text on a filled, bordered box (a quarter of the font size of padding) whose top-left
    /// corner is at (x, y).
    pub fn boxed_text(&mut self, x: f64, y: f64, size: f32, text: &str, style: BoxStyle) -> Label {
        let pad = (size / 4.0).ceil() as i64;
        let w = Canvas::text_width(text, size).ceil() as i64;
        let (bx, by) = (x.round() as i64, y.round() as i64);
        let h = size.ceil() as i64 + 2 * pad;
        self.fill(bx, by, w + 2 * pad, h, style.fill);
        self.frame(bx, by, w + 2 * pad, h, style.border);
        self.text((bx + pad) as f64, (by + pad) as f64, size, text, style.ink)
    }

    /// Render `label`'s text alone on `background` at the same size: what its box must show.
    pub fn render_alone(label: &Label, background: [u8; 3]) -> Canvas {
        let mut c = Canvas::new(
            label.width.max(1) as usize,
            label.height.max(1) as usize,
            background,
        );
        c.draw_text(0.0, 0.0, label.size, &label.text, label.colour);
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_font_parses_and_draws_ink() {
        assert!(font().is_some());
        let mut c = Canvas::new(200, 40, [255, 255, 255]);
        let l = c.text(5.0, 5.0, 20.0, "+0.30 mm", [0, 0, 0]);
        assert!(l.width > 40 && l.width < 120, "{l:?}");
        let ink = c.rgb.chunks(3).filter(|p| p[0] < 128).count();
        assert!(ink > 60, "{ink} dark pixels");
        // Nothing outside the label's box.
        for y in 0..40i64 {
            for x in 0..200i64 {
                let inside =
                    x >= l.x - 2 && x < l.x + l.width + 2 && y >= l.y - 2 && y < l.y + l.height + 4;
                if !inside {
                    assert_eq!(c.get(x, y), Some([255, 255, 255]), "ink at {x},{y}");
                }
            }
        }
    }

    #[test]
    fn huge_circles_and_far_lines_cost_no_more_than_the_canvas() {
        let mut c = Canvas::new(64, 48, [255, 255, 255]);
        // Unbounded, these would take ceil(2π·1e12) and 1e15 steps.
        c.circle((32.0, 24.0), 1e12, [0, 0, 0], 1);
        c.line((0.0, 0.0), (1e15, 3.0), [0, 0, 0], 1, 0);
        c.circle((32.0, 24.0), f64::NAN, [0, 0, 0], 1);
        assert!(c.rgb.contains(&0), "the line's visible part is drawn");
    }
}
