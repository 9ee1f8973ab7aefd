use pointreggpt::sources::threedmatch;
use pointreggpt::tsdf::{TsdfConfig, TsdfVolume};
use std::time::Instant;
fn main() {
    let dir = std::path::Path::new("/work/shared/realdata/7scenes-redkitchen");
    let seqs = threedmatch::open(dir).unwrap();
    let frames: Vec<_> = seqs[0].frames[..50].iter().map(|f| f.load().unwrap()).collect();
    let cfg = TsdfConfig::threedmatch();
    let mut v = TsdfVolume::new(cfg.clone()).unwrap();
    for f in &frames { v.integrate(&f.depth, &f.intrinsics, &f.t_world_from_camera.unwrap()).unwrap(); }
    for _ in 0..5 {
        let t = Instant::now();
        let r = v.raycast(&frames[25].intrinsics, &frames[25].t_world_from_camera.unwrap()).unwrap();
        let rc = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let p = v.extract_points(3.0);
        let ep = t.elapsed().as_secs_f64() * 1e3;
        println!("raycast {rc:.1} ms ({} px) {:?} points {ep:.1}ms {}", r.valid_count(), pointreggpt::tsdf::raycast::raycast_counts(), p.len());
    }
}
