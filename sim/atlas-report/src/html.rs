//! The report page: plain HTML with an inline style sheet; every text from the inputs escaped.

use std::fmt::Write;

use stylet_atlas::import::steps::Step;
use stylet_atlas::import::window;
use stylet_atlas::summary::Summary;

use crate::ReportInput;
use crate::images::Picture;

/// `text` with `& < > " '` escaped (structure names come from user-supplied class tables).
pub(crate) fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Readable on a phone too: the page follows the screen's width (the viewport tag in [`head`]),
/// tables scroll sideways inside their own box, long words and the content hash break, pictures
/// shrink to fit.
const STYLE: &str = "body{font-family:sans-serif;margin:24px auto;padding:0 12px;max-width:1180px;color:#1d2530;\
line-height:1.4;overflow-wrap:break-word}code{overflow-wrap:anywhere}.scroll{overflow-x:auto;max-width:100%}\
h1{margin-bottom:0}h2{border-bottom:2px solid #d5dbe3;padding-bottom:4px;margin-top:32px}\
.sub{color:#5a6675;margin-top:4px}table{border-collapse:collapse;margin:8px 0}\
td,th{border:1px solid #d5dbe3;padding:3px 8px;text-align:left;vertical-align:top}th{background:#eef2f6}\
td.n{text-align:right;font-variant-numeric:tabular-nums}.sw{display:inline-block;width:18px;height:14px;\
border:1px solid #555;vertical-align:middle}.warn{background:#fff4d6;border-left:5px solid #e0a100;\
padding:6px 10px;margin:6px 0}.ok{background:#e5f6e8;border-left:5px solid #2e9a46;padding:6px 10px}\
.fail{background:#fde4e4;border-left:5px solid #c62828;padding:6px 10px}.approve{border:2px solid #1d2530;\
padding:10px 14px;margin:16px 0}figure{margin:12px 0}figure img{max-width:100%;height:auto;box-sizing:border-box;\
border:1px solid #d5dbe3}figcaption{color:#5a6675;font-size:90%}.views{display:flex;gap:12px;flex-wrap:wrap}\
.views figure{flex:1 1 540px;min-width:0}";

/// The page's head: the title, the style sheet, and the viewport tag without which a phone lays
/// the page out 980 px wide and shrinks it.
fn head(name: &str) -> String {
    format!(
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>Validation report: {name}</title><style>{STYLE}</style></head>"
    )
}

/// `html` with every table in a box of its own that scrolls sideways, so that a wide table never
/// widens the page (the page's tables are written as a bare `<table>`; names from the inputs are
/// escaped, so no text holds one).
fn scrolling_tables(html: &str) -> String {
    html.replace("<table>", "<div class=\"scroll\"><table>")
        .replace("</table>", "</table></div>")
}

pub(crate) fn page(input: &ReportInput, pictures: &[Picture]) -> String {
    let atlas = input.atlas;
    let import = input.import;
    let summary = Summary::of(atlas);
    let name = escape(&atlas.manifest.name);
    let mut h = head(&name);
    let _ = write!(
        h,
        "<body><h1>Validation report: {name}</h1>\
         <p class=\"sub\">PTCD scenario made by <code>stylet atlas new</code> from {} and {}; content hash <code>{}</code></p>",
        escape(input.ct_source),
        escape(input.labels_source),
        escape(&atlas.content_hash)
    );
    h += "<div class=\"approve\"><b>For the approving clinician.</b> Check that the structures are where the \
          slices and views show them, that the target duct lies in the liver, that the planned path runs between \
          the ribs it names and clear of the risk structures, and read every warning. Trainees see this patient \
          only once it is published.</div>";
    warnings(&mut h, input);
    source(&mut h, input);
    for p in pictures.iter().take(1) {
        figure(&mut h, p);
    }
    h += "<div class=\"views\">";
    for p in pictures.iter().skip(1) {
        figure(&mut h, p);
    }
    h += "</div>";
    legend(&mut h, input, &summary);
    paths(&mut h, input);
    difficulty(&mut h, input);
    smoke(&mut h, input);
    times(&mut h, input);
    let _ = writeln!(
        h,
        "<h2>Notes of the import</h2><ul>{}</ul></body></html>",
        import
            .notes
            .iter()
            .map(|n| format!("<li>{}</li>", escape(n)))
            .collect::<String>()
    );
    scrolling_tables(&h)
}

fn figure(h: &mut String, p: &Picture) {
    let _ = write!(
        h,
        "<figure><img src=\"{}\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        escape(&p.file),
        escape(&p.caption),
        escape(&p.caption)
    );
}

fn warnings(h: &mut String, input: &ReportInput) {
    let w = &input.import.warnings;
    let _ = write!(h, "<h2>Warnings ({})</h2>", w.len());
    if w.is_empty() {
        *h += "<div class=\"ok\">None: labels cover the body, slices are thin enough, the expected structures are \
               labelled and the CT values are those of a calibrated scan.</div>";
    }
    for x in w {
        let _ = write!(
            h,
            "<div class=\"warn\"><b>{}:</b> {}</div>",
            escape(x.kind.title()),
            escape(&x.text)
        );
    }
}

fn source(h: &mut String, input: &ReportInput) {
    let s = &input.import.source;
    let slices = match s.labelled_slices {
        Some((a, b)) => format!("{a} … {b} of 0 … {}", s.dims[2].saturating_sub(1)),
        None => "none".into(),
    };
    let _ = write!(
        h,
        "<h2>Scan</h2><table>\
         <tr><th>grid</th><td>{} × {} × {} voxels of {:.2} × {:.2} × {:.2} mm</td></tr>\
         <tr><th>CT values</th><td>{:.0} … {:.0} HU{}; body median {}</td></tr>\
         <tr><th>label coverage</th><td>{:.0} % of the body's voxels (CT ≥ {:.0} HU) labelled; labels on axial slices {}</td></tr>\
         <tr><th>structure names</th><td>from {}</td></tr></table>",
        s.dims[0],
        s.dims[1],
        s.dims[2],
        s.spacing_mm[0],
        s.spacing_mm[1],
        s.spacing_mm[2],
        s.hu_min,
        s.hu_max,
        s.padding
            .map(|(v, n)| format!(
                " ({v:.0} HU padding outside the field of view on {:.0} % of the voxels)",
                100.0 * n as f64 / (s.dims.iter().product::<usize>().max(1)) as f64
            ))
            .unwrap_or_default(),
        s.tissue_median_hu
            .map(|m| format!("{m:.0} HU"))
            .unwrap_or_else(|| "n/a".into()),
        100.0 * s.coverage(),
        stylet_atlas::import::checks::TISSUE_HU,
        slices,
        escape(&input.import.classes.source),
    );
}

fn legend(h: &mut String, input: &ReportInput, summary: &Summary) {
    let model = &input.atlas.model;
    let table = model.label_table();
    *h += "<h2>Structures</h2><p>Every label of the scenario with its colour in the slices and on the cut of the \
           3D views, its role in scoring and its tissue (mechanics and ultrasound). Air, skin, soft tissue, bone \
           and cavity are classified by CT value and depth (thesis eq. 6.1.1); the rest come from the label map.</p>\
           <table><tr><th></th><th>id</th><th>structure</th><th>role</th><th>tissue</th><th>voxels</th><th>ml</th>\
           <th>if hit</th></tr>";
    for l in &summary.labels {
        let [r, g, b, _] = table
            .position(l.id)
            .map(|p| model.materials().color(p))
            .unwrap_or([128, 128, 128, 255]);
        let consequence = input
            .atlas
            .manifest
            .labels
            .iter()
            .find(|m| m.id == l.id)
            .and_then(|m| m.consequence.clone())
            .unwrap_or_default();
        let _ = write!(
            h,
            "<tr><td><span class=\"sw\" style=\"background:rgb({r},{g},{b})\"></span></td><td class=\"n\">{}</td>\
             <td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{:.1}</td><td>{}</td></tr>",
            l.id,
            escape(&l.name),
            escape(&l.role),
            escape(&l.tissue),
            l.voxels,
            l.volume_ml,
            escape(&consequence)
        );
    }
    *h += "</table>";
}

fn paths(h: &mut String, input: &ReportInput) {
    let import = input.import;
    *h += "<h2>Target and entry</h2>";
    if let Some(b) = &import.biliary {
        let _ = write!(
            h,
            "<p>Synthetic dilated biliary tree grown from the {} at ({:.1}, {:.1}, {:.1}) mm: {} duct and {} target \
             voxels, {} connected piece(s); target centre ({:.1}, {:.1}, {:.1}) mm.</p>",
            escape(b.hilum_source),
            b.hilum_mm.x,
            b.hilum_mm.y,
            b.hilum_mm.z,
            b.duct_voxels,
            b.target_voxels,
            b.components,
            b.target_center_mm.x,
            b.target_center_mm.y,
            b.target_center_mm.z
        );
    }
    let classes = &import.classes;
    match &import.window {
        Some(w) => {
            let _ = write!(
                h,
                "<p>Straight lines from the target to the skin that cross no bone and no risk structure, \
                 each named by the ribs (or costal cartilage) nearest above and below it where it crosses the \
                 chest wall, both within {near:.0} mm of it. Each space's best line is listed, ranked by \
                 clinical score: windows whose wall segment comes within {recess:.0} mm of the lung pass \
                 through the pleural recess (marked transpleural) and rank last; then by penalty points — \
                 a point per mm closer than {vessel:.0} mm to a vessel or organ at risk, per mm closer than \
                 {bone:.0} mm to bone, per {len:.0} mm of length, per {tilt:.0}° out of the axial plane and per \
                 {tilt:.0}° the approach turns more than {free:.0}° from the side (the mid-axillary line). \
                 Beginners are guided along the chosen one.</p>\
                 <table><tr><th>rank</th><th>intercostal window</th><th>bounds (distance to the path at the wall)</th>\
                 <th>entry (mm)</th><th>length</th><th>tilt</th><th>from the side</th><th>clear of vessels</th><th>clear of bone</th>\
                 <th>lung at the wall</th><th>pleura</th><th>penalty</th><th>chosen</th></tr>",
                near = window::BOUND_NEAR_MM,
                recess = window::PLEURAL_RECESS_MM,
                vessel = window::VESSEL_MARGIN_MM,
                bone = window::BONE_MARGIN_MM,
                len = window::LENGTH_MM_PER_POINT,
                tilt = window::TILT_DEG_PER_POINT,
                free = window::LATERAL_FREE_DEG,
            );
            for (rank, f) in w.ranked.iter().enumerate() {
                let chosen = w
                    .found
                    .as_ref()
                    .is_some_and(|c| (c.upper, c.lower) == (f.upper, f.lower));
                let why = match (chosen, w.choice()) {
                    (false, _) => "",
                    (true, window::Choice::Requested) => "yes (the space asked for)",
                    (true, _) => "yes (best ranked)",
                };
                let lung = if f.lung_clearance_mm.is_finite() {
                    format!("{:.0} mm", f.lung_clearance_mm)
                } else {
                    "no lung".into()
                };
                let lateral = f.lateral_deg.map(|a| format!("{a:.0}°")).unwrap_or_else(|| "–".into());
                let _ = write!(
                    h,
                    "<tr><td class=\"n\">{}</td><td>{}</td><td>{} ({:.1} mm) / {} ({:.1} mm)</td>\
                     <td>({:.1}, {:.1}, {:.1})</td><td class=\"n\">{:.0} mm</td><td class=\"n\">{:.0}°</td>\
                     <td class=\"n\">{lateral}</td>\
                     <td class=\"n\">{:.1} mm</td><td class=\"n\">{:.1} mm</td><td class=\"n\">{lung}</td>\
                     <td>{}</td><td class=\"n\">{:.1}</td><td>{why}</td></tr>",
                    rank + 1,
                    escape(&window::space_name(classes, f.upper, f.lower)),
                    escape(&classes.describe(f.upper)),
                    f.upper_distance_mm,
                    escape(&classes.describe(f.lower)),
                    f.lower_distance_mm,
                    f.entry_mm.x,
                    f.entry_mm.y,
                    f.entry_mm.z,
                    f.length_mm,
                    f.tilt_deg,
                    f.vessel_clearance_mm,
                    f.bone_clearance_mm,
                    if f.transpleural() { "transpleural" } else { "clear" },
                    f.penalty(),
                );
            }
            if !w.requested_found {
                let _ = write!(
                    h,
                    "<tr><td></td><td>{}</td><td>{} / {}</td><td colspan=\"10\">asked for, but no straight line \
                     from the skin between these ribs, within {:.0} mm of both, reaches the target clear of bone and \
                     risk structures</td></tr>",
                    escape(&window::space_name(classes, w.requested.0, w.requested.1)),
                    escape(&classes.describe(w.requested.0)),
                    escape(&classes.describe(w.requested.1)),
                    window::BOUND_NEAR_MM
                );
            }
            *h += "</table>";
        }
        None => *h += "<p>No rib labels: no intercostal window was searched.</p>",
    }
    *h += "<table><tr><th>planned path</th><th>description</th></tr>";
    for p in &input.atlas.manifest.paths {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td></tr>",
            escape(&p.name),
            escape(&p.description)
        );
    }
    *h += "</table>";
}

/// The difficulty presets as this patient's atlas declares them, with why (`import::presets`).
fn difficulty(h: &mut String, input: &ReportInput) {
    let d = &input.atlas.manifest.difficulty;
    *h += "<h2>Difficulty presets</h2><p>What each level shows and follows on this patient (thesis §6.3: \
           the level changes the visual aids).</p><table><tr><th>level</th><th>target shown</th>\
           <th>risk structures shown</th><th>needle guide</th><th>guided path</th><th>why</th></tr>";
    let yes = |b: bool| if b { "yes" } else { "no" };
    let notes = input.import.presets.as_ref();
    for (level, p, note) in [
        ("beginner", &d.beginner, notes.map(|n| n.beginner.as_str())),
        ("advanced", &d.advanced, notes.map(|n| n.advanced.as_str())),
        ("expert", &d.expert, notes.map(|n| n.expert.as_str())),
    ] {
        let _ = write!(
            h,
            "<tr><td>{level}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            yes(p.target_overlay),
            yes(p.risk_overlay),
            yes(p.needle_guide),
            escape(p.guided_path.as_deref().unwrap_or("—")),
            escape(note.unwrap_or("the scenario's preset"))
        );
    }
    *h += "</table>";
}

fn smoke(h: &mut String, input: &ReportInput) {
    *h += "<h2>Smoke test</h2><p>The example scripts along the guided path, recorded and scored as a \
           trainee's session is.</p>";
    if input.smoke.is_empty() {
        *h += "<div class=\"warn\">No example scripts: the scenario has no planned path.</div>";
    }
    for s in input.smoke {
        let _ = write!(
            h,
            "<div class=\"{}\"><b>scripts/{}: {}</b> — must: {}; did: {} ({:.1} s)</div>",
            if s.passed { "ok" } else { "fail" },
            escape(&s.script),
            if s.passed { "passed" } else { "FAILED" },
            escape(&s.expected),
            escape(&s.got),
            s.seconds
        );
    }
}

fn times(h: &mut String, input: &ReportInput) {
    let t = &input.import.timings;
    *h += "<h2>Time per step</h2><table><tr><th>step</th><th>seconds</th></tr>";
    for (step, d) in t {
        let _ = write!(
            h,
            "<tr><td>{}</td><td class=\"n\">{:.1}</td></tr>",
            escape(Step::describe(*step)),
            d.as_secs_f64()
        );
    }
    let total: f64 = t.iter().map(|(_, d)| d.as_secs_f64()).sum();
    let smoke: f64 = input.smoke.iter().map(|s| s.seconds).sum();
    let _ = write!(
        h,
        "<tr><td>smoke test</td><td class=\"n\">{smoke:.1}</td></tr><tr><th>total</th><th class=\"n\">{:.1}</th></tr></table>",
        total + smoke
    );
}

#[cfg(test)]
mod tests {
    use super::{escape, head, scrolling_tables};

    #[test]
    fn the_page_fits_a_phone() {
        let h = head("abdomen &amp; more");
        assert!(h.contains("<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"));
        assert!(h.contains("<title>Validation report: abdomen &amp; more</title>"));
        for rule in [
            ".scroll{overflow-x:auto;max-width:100%}",
            "code{overflow-wrap:anywhere}",
            "figure img{max-width:100%;height:auto;box-sizing:border-box;",
            ".views figure{flex:1 1 540px;min-width:0}",
        ] {
            assert!(h.contains(rule), "no {rule} in {h}");
        }
        let body = "<h2>A</h2><table><tr><td>1</td></tr></table><p>x</p><table><tr><th>b</th></tr></table>";
        let wrapped = scrolling_tables(body);
        assert_eq!(
            wrapped,
            "<h2>A</h2><div class=\"scroll\"><table><tr><td>1</td></tr></table></div><p>x</p>\
             <div class=\"scroll\"><table><tr><th>b</th></tr></table></div>"
        );
        assert_eq!(
            wrapped.matches("<table").count(),
            wrapped.matches("<div class=\"scroll\"><table").count()
        );
    }

    #[test]
    fn markup_in_names_is_escaped() {
        assert_eq!(
            escape("<script>alert('x')</script> & \"y\""),
            "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; &amp; &quot;y&quot;"
        );
    }
}
