use stylet_physics::glam::DVec3;
fn main() {
    let a = stylet_atlas::load(std::path::Path::new("/tmp/d12/atlases/phantom")).unwrap();
    let m = &a.model;
    for zi in 0..=40 {
        let z = -5.0 + zi as f64 * 0.5;
        let p = DVec3::new(150.0, 8.0, z);
        let g = m.skin_distance().gradient(p, -1000.0);
        println!(
            "z {z:6.1} D_skin {:7.3} grad ({:6.3},{:6.3},{:6.3}) hu {:7.1} D_bone {:7.2}",
            m.skin_distance().sample(p, -1000.0),
            g.x,
            g.y,
            g.z,
            m.hu_at(DVec3::new(152.5, 8.0, z)),
            m.bone_distance().sample(p, -1000.0)
        );
    }
}
