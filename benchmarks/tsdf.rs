//! quick timing (temporary)
use pointreggpt::sources::threedmatch;
use pointreggpt::tsdf::{TsdfConfig, TsdfVolume};
use std::time::Instant;
fn main() {
    let dir = std::path::Path::new("/work/shared/realdata/7scenes-redkitchen");
    let seqs = threedmatch::open(dir).unwrap();
    let frames: Vec<_> = seqs[0].frames[..50].iter().map(|f| f.load().unwrap()).collect();
    for cfg in [TsdfConfig::coarse(), TsdfConfig::threedmatch()] {
        for _ in 0..3 {
            let mut v = TsdfVolume::new(cfg.clone()).unwrap();
            let t = Instant::now();
            for f in &frames { v.integrate(&f.depth, &f.intrinsics, &f.t_world_from_camera.unwrap()).unwrap(); }
            let integ = t.elapsed().as_secs_f64() * 1e3 / 50.0;
            let t = Instant::now();
            let p = v.extract_points(3.0);
            let ep = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let m = v.extract_mesh(3.0);
            let em = t.elapsed().as_secs_f64() * 1e3;
            let t = Instant::now();
            let r = v.raycast(&frames[25].intrinsics, &frames[25].t_world_from_camera.unwrap()).unwrap();
            let rc = t.elapsed().as_secs_f64() * 1e3; println!("{:?}", pointreggpt::tsdf::raycast::raycast_counts());
            println!("voxel {} blocks {} integrate {integ:.2} ms/frame, points {} in {ep:.1} ms, mesh {} tris in {em:.1} ms, raycast {rc:.1} ms ({} px)", cfg.voxel_size_m, v.block_count(), p.len(), m.triangles.len(), r.valid_count());
        }
    }
}
