//! MPR (docs/rendering.md "MPR"): marked voxels land on the right pixels in every plane, the
//! general slice path draws what `render_slice` draws, the oblique plane contains the needle,
//! the scale bar is as long as it says and the tip marker sits on the tip; the phantom's four
//! views with overlays (written as PNGs when STYLET_MPR_PNG_DIR is set, to look at).

use std::sync::OnceLock;

use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, PunctureAtlas, Role};
use stylet_render::annotate::{Annotations, BAR_RGB, NEEDLE_RGB, ScaleBar, TIP_RGB, annotate, bar_origin};
use stylet_render::image::Image;
use stylet_render::mpr::{MprError, Plane, SliceSpec, Window, render_slice, render_spec};
use stylet_render::synthetic;

/// Marker centres (world mm) and their labels: A in the middle, R to the patient's right of it
/// (+x), N anterior (+y), S superior (+z).
const A: DVec3 = DVec3::new(0.0, 0.0, 0.0);
const R: DVec3 = DVec3::new(24.0, 0.0, 0.0);
const N: DVec3 = DVec3::new(0.0, 21.0, 0.0);
const S: DVec3 = DVec3::new(0.0, 0.0, 20.0);
const MARKERS: [(DVec3, u16); 4] = [(A, 10), (R, 11), (N, 12), (S, 13)];

/// An anisotropic grid (1.5 × 1.5 × 2 mm, voxel centres on the markers) of 0 HU with 3 × 3 × 3
/// voxel markers of 300 HU carrying labels 10 … 13.
fn marker_atlas() -> &'static PunctureAtlas {
    static ATLAS: OnceLock<PunctureAtlas> = OnceLock::new();
    ATLAS.get_or_init(|| {
        let g = Grid::new(
            [48, 44, 40],
            Affine::from_spacing([1.5, 1.5, 2.0], DVec3::new(-36.0, -33.0, -40.0)),
        )
        .unwrap();
        let mut ct = vec![0.0f32; g.len()];
        let mut labels = vec![0u16; g.len()];
        for (i, v) in ct.iter_mut().enumerate() {
            let [a, b, c] = g.unlinear(i);
            let p = g.voxel_to_world(a, b, c);
            for (m, id) in MARKERS {
                let d = p - m;
                if d.x.abs() < 2.0 && d.y.abs() < 2.0 && d.z.abs() < 2.5 {
                    *v = 300.0;
                    labels[i] = id;
                }
            }
        }
        synthetic::atlas_with(
            g,
            ct,
            labels,
            &[
                (10, "a", Role::Target),
                (11, "r", Role::Organ),
                (12, "n", Role::Organ),
                (13, "s", Role::Organ),
            ],
        )
    })
}

/// Centroid (col, row) of the pixels carrying `label`, and their count.
fn centroid(labels: &[u16], width: usize, label: u16) -> ((f64, f64), usize) {
    let (mut sc, mut sr, mut n) = (0.0, 0.0, 0usize);
    for (i, &l) in labels.iter().enumerate() {
        if l == label {
            sc += (i % width) as f64;
            sr += (i / width) as f64;
            n += 1;
        }
    }
    ((sc / n.max(1) as f64, sr / n.max(1) as f64), n)
}

#[test]
fn standard_planes_put_marked_voxels_where_they_are() {
    let atlas = marker_atlas();
    for plane in [Plane::Axial, Plane::Coronal, Plane::Sagittal] {
        let s = render_slice(atlas, plane, A, Window::ABDOMEN, 150);
        let (c, r) = s.pixel(A);
        let (got, n) = centroid(&s.labels, s.width, 10);
        assert!(n > 4, "{plane:?}: marker A not in the slice");
        assert!(
            (got.0 - c).abs() < 0.75 && (got.1 - r).abs() < 0.75,
            "{plane:?}: A at {got:?}, expected ({c}, {r})"
        );
        // The marker's label colour is blended in there (not the window's grey of 300 HU).
        let px = s.rgb[r.round() as usize * s.width + c.round() as usize];
        let g = Window::ABDOMEN.gray(300.0);
        assert_ne!(px, [g, g, g], "{plane:?}");
        // Radiological orientation, checked against the markers' known world offsets.
        let at = |label: u16| centroid(&s.labels, s.width, label);
        match plane {
            Plane::Axial => {
                // Patient's right on the image's left; anterior up; S is not in this slice.
                assert!(at(11).0.0 < got.0 - 10.0 && (at(11).0.1 - got.1).abs() < 1.0);
                assert!(at(12).0.1 < got.1 - 10.0 && (at(12).0.0 - got.0).abs() < 1.0);
                assert_eq!(at(13).1, 0);
            }
            Plane::Coronal => {
                assert!(at(11).0.0 < got.0 - 10.0);
                assert!(at(13).0.1 < got.1 - 10.0 && (at(13).0.0 - got.0).abs() < 1.0);
                assert_eq!(at(12).1, 0);
            }
            Plane::Sagittal => {
                // Anterior on the left, superior up.
                assert!(at(12).0.0 < got.0 - 10.0);
                assert!(at(13).0.1 < got.1 - 10.0);
                assert_eq!(at(11).1, 0);
            }
        }
        // And the marker distances in pixels are the world distances over the pixel size.
        let (other, id) = match plane {
            Plane::Sagittal => (N, 12),
            _ => (R, 11),
        };
        let (oc, _) = s.pixel(other);
        assert!((at(id).0.0 - oc).abs() < 0.75, "{plane:?}: {:?} vs {oc}", at(id).0);
    }
}

#[test]
fn slice_specs_draw_what_render_slice_draws() {
    let atlas = marker_atlas();
    let center = DVec3::new(3.0, -4.0, 5.0);
    for plane in [Plane::Axial, Plane::Coronal, Plane::Sagittal] {
        let s = render_slice(atlas, plane, center, Window::ABDOMEN, 120);
        let spec = SliceSpec::plane(atlas, plane, center, Window::ABDOMEN, 120);
        assert_eq!(
            (spec.width, spec.height, spec.pixel_mm),
            (s.width, s.height, s.pixel_mm)
        );
        assert_eq!(spec, s.spec);
        for (c, r) in [(0.0, 0.0), (s.width as f64 - 1.0, 0.0), (7.0, s.height as f64 - 1.0)] {
            assert!((spec.world(c, r) - s.world(c, r)).abs().max_element() < 1e-9);
        }
        // The slice passes through the centre point.
        assert!(spec.distance_mm(center).abs() < 1e-9);
        assert_eq!(spec.edge_letters(), plane.edge_letters());
        let img = render_spec(atlas, &spec).unwrap();
        assert_eq!(img.rgb, s.rgb);
        assert_eq!(img.labels, s.labels);
    }
    // Bad specs are refused by name.
    let spec = SliceSpec::plane(atlas, Plane::Axial, center, Window::ABDOMEN, 120);
    let bad = SliceSpec { width: 0, ..spec };
    assert!(matches!(render_spec(atlas, &bad), Err(MprError::Size { .. })));
    let bad = SliceSpec {
        pixel_mm: f64::NAN,
        ..spec
    };
    assert!(matches!(render_spec(atlas, &bad), Err(MprError::PixelSize(_))));
    let bad = SliceSpec {
        down: spec.right,
        ..spec
    };
    assert!(matches!(render_spec(atlas, &bad), Err(MprError::Axes { .. })));
}

#[test]
fn oblique_plane_contains_the_needle() {
    let atlas = marker_atlas();
    let tangents = [
        DVec3::new(0.3, -0.5, -0.8),
        DVec3::new(-0.9, 0.1, -0.2),
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(0.01, 0.02, -1.0), // nearly vertical: the posterior fallback
        DVec3::new(0.0, 0.0, 1.0),
    ];
    for t in tangents {
        let t = t.normalize();
        let tip = A;
        let spec = SliceSpec::oblique_along_needle(tip, t, 0.8, 121, 101, Window::ABDOMEN).unwrap();
        // The needle's nodes (150 mm back from the tip) lie within half a pixel of the plane.
        for j in 0..31 {
            let node = tip - t * (5.0 * j as f64);
            assert!(spec.distance_mm(node).abs() < 0.5 * spec.pixel_mm, "{t}: node {j}");
        }
        // The tip at the centre pixel; superior up; the tangent in the image.
        let (c, r) = spec.pixel(tip);
        assert!((c - 60.0).abs() < 1e-9 && (r - 50.0).abs() < 1e-9);
        assert!(spec.down.z <= 0.0, "{t}: down {}", spec.down);
        let in_plane = t.dot(spec.right).powi(2) + t.dot(spec.down).powi(2);
        assert!((in_plane - 1.0).abs() < 1e-9);
        // Marker A (at the tip) is drawn at the centre.
        let img = render_spec(atlas, &spec).unwrap();
        let (got, n) = centroid(&img.labels, spec.width, 10);
        assert!(
            n > 10 && (got.0 - 60.0).abs() < 1.0 && (got.1 - 50.0).abs() < 1.0,
            "{t}: {got:?}"
        );
        if (t.x * t.x + t.y * t.y).sqrt() >= 0.1 {
            assert_eq!(spec.down, DVec3::NEG_Z);
        } else {
            // Vertical: spanned by the tangent and posterior.
            assert!(spec.right.y < -0.99, "{}", spec.right);
        }
    }
    assert!(matches!(
        SliceSpec::oblique_along_needle(A, DVec3::ZERO, 1.0, 10, 10, Window::ABDOMEN),
        Err(MprError::Tangent(_))
    ));
}

fn flat_image(spec: &SliceSpec) -> Image {
    let mut img = Image::new(spec.width as u32, spec.height as u32);
    for p in &mut img.rgba {
        *p = [40, 40, 40, 255];
    }
    img
}

#[test]
fn scale_bar_is_as_long_as_it_says() {
    for (pixel_mm, width) in [(0.5, 400), (0.7, 480), (0.25, 300), (1.3, 200)] {
        let spec = SliceSpec {
            center_mm: DVec3::ZERO,
            right: DVec3::NEG_X,
            down: DVec3::NEG_Y,
            pixel_mm,
            width,
            height: 240,
            window: Window::ABDOMEN,
        };
        let mut img = flat_image(&spec);
        let ann = Annotations {
            scale_bar: true,
            ..Default::default()
        };
        annotate(&mut img, &spec, &ann).unwrap();
        let bar = ScaleBar::for_slice(pixel_mm, width);
        assert_eq!(bar.length_px, (bar.length_mm / pixel_mm).round() as i32);
        let (_, y0) = bar_origin(&bar, width as i32, 240);
        let white = [BAR_RGB[0], BAR_RGB[1], BAR_RGB[2], 255];
        let count = (0..width as u32)
            .filter(|&x| img.get(x, (y0 + 1) as u32) == white)
            .count();
        assert_eq!(count as i32, bar.length_px, "{pixel_mm} mm/px");
        // The text above it drew something.
        let text = (0..width as u32)
            .flat_map(|x| (y0 - 20..y0).map(move |y| (x, y as u32)))
            .filter(|&(x, y)| img.get(x, y) != [40, 40, 40, 255])
            .count();
        assert!(text > 10, "no scale text at {pixel_mm} mm/px");
    }
}

#[test]
fn tip_marker_and_path_sit_on_the_needle() {
    let spec = SliceSpec {
        center_mm: DVec3::ZERO,
        right: DVec3::NEG_X,
        down: DVec3::NEG_Z,
        pixel_mm: 0.5,
        width: 200,
        height: 160,
        window: Window::ABDOMEN,
    };
    // A needle in the coronal plane from upper left to the tip 10 mm right of the centre.
    let tip = DVec3::new(-10.0, 0.0, 0.0);
    let hub = DVec3::new(30.0, 0.0, 25.0);
    let nodes: Vec<DVec3> = (0..=10).map(|j| hub + (tip - hub) * (j as f64 / 10.0)).collect();
    let mut img = flat_image(&spec);
    annotate(
        &mut img,
        &spec,
        &Annotations {
            needle_mm: nodes,
            ..Default::default()
        },
    )
    .unwrap();
    let (c, r) = spec.pixel(tip);
    assert_eq!((c, r), (119.5, 79.5));
    let is = |x: f64, y: f64, rgb: [u8; 3]| {
        let mut hit = false;
        for dx in -1..=1 {
            for dy in -1..=1 {
                let p = img.get((x.round() as i32 + dx) as u32, (y.round() as i32 + dy) as u32);
                hit |= p[..3] == rgb;
            }
        }
        hit
    };
    // The ring around the tip and its cross arms.
    for (dx, dy) in [
        (9.0, 0.0),
        (-9.0, 0.0),
        (0.0, 9.0),
        (0.0, -9.0),
        (14.0, 0.0),
        (0.0, -14.0),
    ] {
        assert!(is(c + dx, r + dy, TIP_RGB), "tip marker missing at ({dx}, {dy})");
    }
    // The path halfway along the needle.
    let (mc, mr) = spec.pixel((tip + hub) * 0.5);
    assert!(is(mc, mr, NEEDLE_RGB));
    // Far from both: untouched.
    assert_eq!(img.get(10, 150), [40, 40, 40, 255]);
    // A mismatched image is refused.
    let mut small = Image::new(10, 10);
    assert!(annotate(&mut small, &spec, &Annotations::default()).is_err());
}

#[test]
fn phantom_views_with_overlays() {
    let dir = tempfile::tempdir().unwrap();
    let config = stylet_atlas::phantom::PhantomConfig {
        dims: [128, 128, 100],
        spacing_mm: [3.0, 3.0, 3.0],
        ..Default::default()
    };
    let p = stylet_atlas::phantom::generate(&config).unwrap();
    stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = stylet_atlas::load(dir.path()).unwrap();
    let path = atlas
        .planned_paths()
        .into_iter()
        .next()
        .expect("the phantom has a planned path");
    let dir_n = path.direction().unwrap();
    // A straight needle along the planned path, 80 % of the way in.
    let tip = path.entry_mm + (path.target_mm - path.entry_mm) * 0.8;
    let nodes: Vec<DVec3> = (0..31).map(|j| tip - dir_n * (150.0 - 5.0 * j as f64)).collect();
    let model = &atlas.model;
    let out = std::env::var_os("STYLET_MPR_PNG_DIR");
    let mut specs: Vec<(&str, SliceSpec)> = [Plane::Axial, Plane::Coronal, Plane::Sagittal]
        .into_iter()
        .map(|pl| (pl.name(), SliceSpec::plane(model, pl, tip, Window::ABDOMEN, 480)))
        .collect();
    specs.push((
        "needle",
        SliceSpec::oblique_along_needle(tip, dir_n, 0.75, 480, 400, Window::ABDOMEN).unwrap(),
    ));
    for (name, spec) in specs {
        let slice = render_spec(model, &spec).unwrap();
        // The body is there: most of the central pixels are not air-black.
        let lit = slice.rgb.iter().filter(|p| p.iter().any(|&c| c > 30)).count();
        assert!(lit > slice.rgb.len() / 4, "{name}: {lit} of {} pixels", slice.rgb.len());
        let mut img = slice.to_image();
        let ann = Annotations {
            needle_mm: nodes.clone(),
            scale_bar: true,
            letters: true,
        };
        annotate(&mut img, &spec, &ann).unwrap();
        let (c, r) = spec.pixel(tip);
        let ring = (0..360).step_by(10).any(|deg| {
            let a = (deg as f64).to_radians();
            let (x, y) = (c + 9.0 * a.cos(), r + 9.0 * a.sin());
            img.get(x.round() as u32, y.round() as u32)[..3] == TIP_RGB
        });
        assert!(ring, "{name}: no tip marker at ({c:.1}, {r:.1})");
        if let Some(d) = &out {
            let file = std::path::Path::new(d).join(format!("mpr-{name}.png"));
            img.write_png(&file).unwrap();
        }
    }
    // The oblique plane holds the whole needle.
    let spec = SliceSpec::oblique_along_needle(tip, dir_n, 0.75, 480, 400, Window::ABDOMEN).unwrap();
    assert!(nodes.iter().all(|n| spec.distance_mm(*n).abs() < 0.5 * spec.pixel_mm));
}
