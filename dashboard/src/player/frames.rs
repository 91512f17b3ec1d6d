//! The player's frames: the views of a moment drawn on the CPU reference renderers with the
//! scenes `stylet_render::views` composes, so a frame equals `stylet render --session … --at …`
//! of the same tick (3D with `--tagging risk`: instructors see inside), and a disk cache for them
//! with a size limit.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use stylet_atlas::Atlas;
use stylet_render::image::Image;
use stylet_render::mpr::Plane;
use stylet_render::presets::Preset;
use stylet_render::scene::Tagging;
use stylet_render::ultrasound::{self, EchoTable};
use stylet_render::views::{self, Moment, ViewError};
use stylet_render::volume::RenderVolume;

/// The views the player shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameView {
    /// The ray-cast patient with the tools, risk structures tagged, cut along the tool.
    ThreeD,
    /// The axial slice through the tip with the label overlay.
    Axial,
    /// The probe in hand, else a convex probe beside the planned path.
    Ultrasound,
    /// The scenario's C-arm with the needle and the contrast medium.
    Xray,
}

impl FrameView {
    pub const ALL: [FrameView; 4] = [
        FrameView::ThreeD,
        FrameView::Axial,
        FrameView::Ultrasound,
        FrameView::Xray,
    ];

    /// The name in URLs (the same as `stylet render --view`).
    pub fn name(self) -> &'static str {
        match self {
            FrameView::ThreeD => "3d",
            FrameView::Axial => "axial",
            FrameView::Ultrasound => "ultrasound",
            FrameView::Xray => "xray",
        }
    }

    pub fn title(self) -> &'static str {
        match self {
            FrameView::ThreeD => "3D",
            FrameView::Axial => "Axial slice through the tip",
            FrameView::Ultrasound => "Ultrasound",
            FrameView::Xray => "X-ray",
        }
    }

    pub fn parse(s: &str) -> Option<FrameView> {
        FrameView::ALL.into_iter().find(|v| v.name() == s)
    }
}

/// The drawing's version, in every cached frame's name with the physics version: raise it when
/// what a frame shows changes (a view's scene, preset or size), so old frames are not served.
pub const FRAME_VERSION: u32 = 2;

/// What drawing an atlas needs besides the atlas: prepared once per atlas.
pub struct AtlasDrawing {
    pub atlas: Arc<Atlas>,
    pub volume: RenderVolume,
    pub echo: Arc<EchoTable>,
}

impl AtlasDrawing {
    pub fn new(atlas: Arc<Atlas>) -> AtlasDrawing {
        AtlasDrawing {
            volume: RenderVolume::new(Arc::clone(&atlas.model)),
            echo: Arc::new(EchoTable::of_atlas(&atlas)),
            atlas,
        }
    }

    /// Draws `view` of the moment at `width` × `height`.
    pub fn draw(&self, view: FrameView, moment: &Moment, width: u32, height: u32) -> Result<Image, ViewError> {
        let atlas = &*self.atlas;
        let m = Some(moment);
        match view {
            FrameView::ThreeD => {
                let scene = views::scene_3d(atlas, m, Preset::Skin, Tagging::Risk, views::default_step_mm(atlas))?;
                Ok(stylet_render::raycast::render(&self.volume, &scene, width, height).image)
            }
            FrameView::Axial => views::slice_image(atlas, m, &views::plane_spec(atlas, m, Plane::Axial, width, height)),
            FrameView::Ultrasound => {
                let scene = views::ultrasound_scene(atlas, m, None, moment.difficulty, Arc::clone(&self.echo), None)?;
                Ok(ultrasound::render(&atlas.model, &scene)?.to_image(width, height))
            }
            FrameView::Xray => {
                let scenario = atlas.manifest.scenarios.iter().find(|s| s.name == moment.scenario);
                let (scene, window) = views::xray_scene(atlas, m, scenario, None, None)?;
                let breathing = moment.breathing.as_ref();
                Ok(
                    stylet_render::xray::render_moving(&atlas.model, &scene, breathing, width, height)?
                        .to_image(window),
                )
            }
        }
    }
}

/// Rendered frames on disk (`DATA/frames/`), at most `max_bytes` in all: the oldest go first.
/// The drawing's and the physics' versions are in each name: a new version draws new frames.
pub struct FrameCache {
    dir: PathBuf,
    max_bytes: u64,
    /// Files in the order they were written (the oldest first), the same as a set, and their
    /// total size; read from the directory on first use.
    index: Mutex<Option<Index>>,
}

struct Index {
    order: VecDeque<(PathBuf, u64)>,
    known: std::collections::HashSet<PathBuf>,
    total: u64,
}

impl FrameCache {
    pub fn new(data_dir: &Path, max_bytes: u64) -> FrameCache {
        FrameCache {
            dir: data_dir.join("frames"),
            max_bytes,
            index: Mutex::new(None),
        }
    }

    /// Where a frame is kept.
    pub fn path(&self, sha: &str, view: FrameView, tick: u64, width: u32, height: u32) -> PathBuf {
        self.dir.join(&sha[..2.min(sha.len())]).join(sha).join(format!(
            "{}-{tick}-{width}x{height}-v{FRAME_VERSION}-p{}.png",
            view.name(),
            stylet_physics::PHYSICS_VERSION
        ))
    }

    /// Where a frame of the 3D overview is kept (`corridor_key`: the expert references drawn).
    pub fn overview_path(&self, sha: &str, frame: u32, corridor_key: &str, width: u32, height: u32) -> PathBuf {
        self.dir.join(&sha[..2.min(sha.len())]).join(sha).join(format!(
            "overview-{frame}-{corridor_key}-{width}x{height}-v{FRAME_VERSION}-p{}.png",
            stylet_physics::PHYSICS_VERSION
        ))
    }

    /// The cached frame, if there is one.
    pub fn get(&self, path: &Path) -> Option<Vec<u8>> {
        std::fs::read(path).ok()
    }

    /// Keeps a frame (written beside its place and renamed: never half a file), then removes the
    /// oldest frames while the cache is over its limit. A frame that cannot be kept is only
    /// logged: it was drawn and is served anyway.
    pub fn put(&self, path: &Path, png: &[u8]) {
        let len = png.len() as u64;
        if len > self.max_bytes {
            return;
        }
        let written = (|| -> std::io::Result<()> {
            let dir = path.parent().ok_or_else(|| std::io::Error::other("no folder"))?;
            std::fs::create_dir_all(dir)?;
            static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
            let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let tmp = path.with_extension(format!("{}-{n}.partial", std::process::id()));
            std::fs::write(&tmp, png)?;
            std::fs::rename(&tmp, path)
        })();
        if let Err(e) = written {
            tracing::warn!(error = %e, path = %path.display(), "cannot keep a player frame");
            return;
        }
        let mut index = self.index.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let index = index.get_or_insert_with(|| scan(&self.dir));
        if index.known.insert(path.to_path_buf()) {
            index.order.push_back((path.to_path_buf(), len));
            index.total += len;
        }
        while index.total > self.max_bytes {
            let Some((old, size)) = index.order.pop_front() else {
                break;
            };
            let _ = std::fs::remove_file(&old);
            index.known.remove(&old);
            index.total = index.total.saturating_sub(size);
        }
    }

    /// Bytes the cache holds now (after its first use).
    pub fn bytes(&self) -> u64 {
        let mut index = self.index.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        index.get_or_insert_with(|| scan(&self.dir)).total
    }
}

/// The frames already on disk, oldest first (by modification time), and their total size.
fn scan(dir: &Path) -> Index {
    let mut found = Vec::new();
    // DATA/frames/<2>/<sha>/<frame>.png: three levels, nothing deeper is looked at.
    let entries = |d: &Path| std::fs::read_dir(d).into_iter().flatten().flatten().map(|e| e.path());
    for prefix in entries(dir) {
        for session in entries(&prefix) {
            for file in entries(&session) {
                if file.extension().is_some_and(|e| e == "png")
                    && let Ok(meta) = file.metadata()
                {
                    let modified = meta.modified().unwrap_or(std::time::SystemTime::UNIX_EPOCH);
                    found.push((modified, file, meta.len()));
                }
            }
        }
    }
    found.sort();
    let total = found.iter().map(|f| f.2).sum();
    let order: VecDeque<(PathBuf, u64)> = found.into_iter().map(|(_, p, len)| (p, len)).collect();
    let known = order.iter().map(|(p, _)| p.clone()).collect();
    Index { order, known, total }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_keeps_at_most_its_limit_and_drops_the_oldest_first() {
        let dir = tempfile::tempdir().unwrap();
        let cache = FrameCache::new(dir.path(), 2500);
        let sha = "ab".repeat(32);
        let paths: Vec<PathBuf> = (0..4).map(|t| cache.path(&sha, FrameView::Axial, t, 64, 64)).collect();
        for p in &paths {
            cache.put(p, &[7u8; 1000]);
        }
        // 4 000 bytes over a 2 500-byte limit: the two oldest are gone.
        assert_eq!(cache.bytes(), 2000);
        assert!(cache.get(&paths[0]).is_none() && cache.get(&paths[1]).is_none());
        assert_eq!(cache.get(&paths[3]).unwrap(), vec![7u8; 1000]);
        // A new server on the same folder finds what is there.
        let again = FrameCache::new(dir.path(), 2500);
        assert_eq!(again.bytes(), 2000);
        // A frame larger than the whole cache is not kept; nothing half-written is left.
        again.put(&paths[0], &[1u8; 3000]);
        assert!(again.get(&paths[0]).is_none());
        let names: Vec<String> = std::fs::read_dir(paths[3].parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| n.ends_with(".png")), "{names:?}");
    }
}
