//! The view panes of the session and the replay: a layout of one, two or four panes, each
//! showing the view the trainee picks, drawn by the [`ViewWorker`] at the pane's size in
//! physical pixels.

use eframe::egui;
use stylet_render::views::Moment;

use crate::view_worker::{DrawnPane, Pane, ViewWorker};
use crate::views::ViewKind;

/// How many panes the views share the window in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    One,
    Two,
    Four,
}

impl Layout {
    pub const ALL: [Layout; 3] = [Layout::One, Layout::Two, Layout::Four];

    pub fn panes(self) -> usize {
        match self {
            Layout::One => 1,
            Layout::Two => 2,
            Layout::Four => 4,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Layout::One => "1 view",
            Layout::Two => "2 views",
            Layout::Four => "4 views",
        }
    }

    /// The next layout (keypad 0 cycles them).
    pub fn next(self) -> Layout {
        match self {
            Layout::One => Layout::Two,
            Layout::Two => Layout::Four,
            Layout::Four => Layout::One,
        }
    }
}

/// The panes and their textures.
pub struct Panes {
    pub layout: Layout,
    /// The view of each pane position (the first `layout.panes()` are shown).
    pub kinds: [ViewKind; 4],
    textures: Vec<Option<(u64, egui::TextureHandle)>>,
    /// Drawing time and scale of each shown pane's latest frame.
    pub timings: Vec<Option<(ViewKind, f64, f32)>>,
    /// Frame times in the pane titles (off for reproducible pictures).
    pub show_timings: bool,
}

impl Default for Panes {
    fn default() -> Self {
        Panes {
            layout: Layout::Four,
            kinds: [ViewKind::ThreeD, ViewKind::Needle, ViewKind::Ultrasound, ViewKind::Xray],
            textures: Vec::new(),
            timings: Vec::new(),
            show_timings: true,
        }
    }
}

impl Panes {
    /// Lays the panes out in the space left, asks the worker for them at `moment`, and paints
    /// what it has drawn. Returns each pane's picture area, for pointer input.
    pub fn ui(&mut self, ui: &mut egui::Ui, worker: &ViewWorker, moment: Option<&Moment>) -> Vec<egui::Response> {
        let n = self.layout.panes();
        let area = ui.available_rect_before_wrap();
        let rects = split(area, self.layout);
        let ppp = ui.ctx().pixels_per_point();
        let title_h = 24.0;
        let mut requests = Vec::with_capacity(n);
        let mut pictures = Vec::with_capacity(n);
        for (i, rect) in rects.iter().enumerate() {
            let picture = egui::Rect::from_min_max(rect.min + egui::vec2(0.0, title_h), rect.max);
            let px = |v: f32| ((v * ppp).round() as u32).clamp(16, 4096);
            requests.push(Pane {
                kind: self.kinds[i],
                width: px(picture.width()),
                height: px(picture.height()),
            });
            pictures.push(picture);
        }
        if let Some(m) = moment {
            worker.request(m, &requests);
        }
        let drawn = worker.drawn();
        self.textures.resize_with(n, || None);
        self.timings = vec![None; n];
        let mut responses = Vec::with_capacity(n);
        for (i, rect) in rects.iter().enumerate() {
            let title = egui::Rect::from_min_size(rect.min, egui::vec2(rect.width(), title_h));
            ui.scope_builder(egui::UiBuilder::new().max_rect(title), |ui| {
                ui.horizontal(|ui| {
                    let combo = egui::ComboBox::from_id_salt(("pane", i))
                        .selected_text(self.kinds[i].title())
                        .show_ui(ui, |ui| {
                            for k in ViewKind::ALL {
                                ui.selectable_value(&mut self.kinds[i], k, k.title());
                            }
                        });
                    super::name_widget(
                        &combo.response,
                        egui::Role::ComboBox,
                        &format!("view of pane {}", i + 1),
                    );
                    if let Some(Some(d)) = drawn.get(i)
                        && self.show_timings
                        && let Ok(f) = &d.frame
                    {
                        ui.weak(format!("{:.0} ms · scale {:.2}", f.took.as_secs_f64() * 1e3, f.scale));
                    }
                });
            });
            let picture = pictures[i];
            let response = ui.interact(
                picture,
                ui.make_persistent_id(("picture", i)),
                egui::Sense::click_and_drag(),
            );
            super::name_widget(&response, egui::Role::Image, self.kinds[i].title());
            let painter = ui.painter_at(picture);
            painter.rect_filled(picture, 0.0, egui::Color32::from_gray(12));
            match drawn.get(i).and_then(Option::as_ref) {
                Some(d) => self.paint(ui, &painter, picture, i, d),
                None => {
                    let text = match (worker.failure(), worker.is_ready(), moment.is_some()) {
                        (Some(e), _, _) => format!("cannot draw: {e}"),
                        (None, false, _) => "preparing the patient for drawing…".into(),
                        (None, true, false) => "waiting for the first tick…".into(),
                        (None, true, true) => "drawing…".into(),
                    };
                    painter.text(
                        picture.center(),
                        egui::Align2::CENTER_CENTER,
                        text,
                        egui::FontId::proportional(14.0),
                        egui::Color32::GRAY,
                    );
                }
            }
            responses.push(response);
        }
        ui.advance_cursor_after_rect(area);
        responses
    }

    fn paint(&mut self, ui: &egui::Ui, painter: &egui::Painter, picture: egui::Rect, i: usize, d: &DrawnPane) {
        match &d.frame {
            Ok(frame) => {
                let img = &frame.image;
                let fresh = !matches!(&self.textures[i], Some((seq, _)) if *seq == d.seq);
                if fresh {
                    let bytes: Vec<u8> = img.rgba.iter().flatten().copied().collect();
                    let color =
                        egui::ColorImage::from_rgba_unmultiplied([img.width as usize, img.height as usize], &bytes);
                    match &mut self.textures[i] {
                        Some((seq, handle)) => {
                            handle.set(color, egui::TextureOptions::LINEAR);
                            *seq = d.seq;
                        }
                        None => {
                            let handle =
                                ui.ctx()
                                    .load_texture(format!("pane-{i}"), color, egui::TextureOptions::LINEAR);
                            self.textures[i] = Some((d.seq, handle));
                        }
                    }
                }
                if let Some((_, handle)) = &self.textures[i] {
                    // Keep the picture's aspect (it was drawn for the pane's size; the pane may
                    // have changed since).
                    let aspect = img.width as f32 / img.height.max(1) as f32;
                    let mut size = picture.size();
                    if size.x / size.y > aspect {
                        size.x = size.y * aspect;
                    } else {
                        size.y = size.x / aspect;
                    }
                    let rect = egui::Rect::from_center_size(picture.center(), size);
                    let uv = egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0));
                    painter.image(handle.id(), rect, uv, egui::Color32::WHITE);
                }
                self.timings[i] = Some((d.pane.kind, frame.took.as_secs_f64() * 1e3, frame.scale));
            }
            Err(e) => {
                painter.text(
                    picture.center(),
                    egui::Align2::CENTER_CENTER,
                    e,
                    egui::FontId::proportional(14.0),
                    egui::Color32::GRAY,
                );
            }
        }
    }
}

/// The panes' rectangles: one, side by side, or a 2 × 2 grid, with a small gap.
fn split(area: egui::Rect, layout: Layout) -> Vec<egui::Rect> {
    let gap = 4.0;
    let (w, h) = (area.width(), area.height());
    let cell = |col: f32, row: f32, cols: f32, rows: f32| {
        let cw = (w - gap * (cols - 1.0)) / cols;
        let ch = (h - gap * (rows - 1.0)) / rows;
        egui::Rect::from_min_size(
            area.min + egui::vec2(col * (cw + gap), row * (ch + gap)),
            egui::vec2(cw.max(16.0), ch.max(16.0)),
        )
    };
    match layout {
        Layout::One => vec![area],
        Layout::Two => vec![cell(0.0, 0.0, 2.0, 1.0), cell(1.0, 0.0, 2.0, 1.0)],
        Layout::Four => vec![
            cell(0.0, 0.0, 2.0, 2.0),
            cell(1.0, 0.0, 2.0, 2.0),
            cell(0.0, 1.0, 2.0, 2.0),
            cell(1.0, 1.0, 2.0, 2.0),
        ],
    }
}
