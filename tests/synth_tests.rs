//! SynthNOCS generator tests: ground-truth self-consistency, mesh
//! normalisation, determinism, masks vs annotations, recording round trip.

use std::path::Path;
use tricons::Category;
use tricons::frame::Intrinsics;
use tricons::image_io::{SizeLimit, read_label_png};
use tricons::recording::open_recording;
use tricons::rng::Rng;
use tricons::synth::mesh::TAG_HANDLE;
use tricons::synth::shapes::generate_object;
use tricons::synth::{MIN_VISIBLE_PX, SynthConfig, SynthFrame, generate, render_frame};

/// Per-frame statistics of the GT self-consistency check.
struct Consistency {
    /// Fraction of back-projected points inside the grown box, per instance.
    inside_fraction: Vec<f64>,
    /// NOCS errors (Euclidean, NOCS units) of every checked pixel.
    nocs_errors: Vec<f64>,
}

/// Back-projects masked valid depth into each instance's object frame and
/// compares with the box and the NOCS map.
fn consistency(f: &SynthFrame, c: &mut Consistency) {
    let k = f.frame.intrinsics;
    let mask = f.annotations.mask.as_ref().expect("mask");
    let nocs = f.annotations.nocs.as_ref().expect("nocs");
    for inst in &f.annotations.instances {
        let inv = inst.camera_from_object.inverse();
        let diag = inst.diagonal_m();
        let (mut n, mut inside) = (0usize, 0usize);
        for v in 0..k.height {
            for u in 0..k.width {
                if mask.label(u, v) != inst.id {
                    continue;
                }
                let Some(z) = f.frame.depth.depth_m(u, v) else { continue };
                let p = inv.transform_point(&k.backproject(f64::from(u), f64::from(v), z));
                n += 1;
                // the GT box grown by 5% (each size x 1.05), as the acceptance criterion states
                if (0..3).all(|a| p[a].abs() <= inst.size_m[a] * 0.5 * 1.05) {
                    inside += 1;
                }
                let q = nocs.coord(u, v);
                let e: f64 = (0..3).map(|a| (q[a] - (p[a] / diag + 0.5)).powi(2)).sum::<f64>().sqrt();
                c.nocs_errors.push(e);
            }
        }
        if n >= 50 {
            c.inside_fraction.push(inside as f64 / n as f64);
        }
    }
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn check_consistency(noise: bool) -> (f64, f64) {
    let cfg = SynthConfig { depth_noise: noise, ..SynthConfig::default() };
    let mut c = Consistency { inside_fraction: Vec::new(), nocs_errors: Vec::new() };
    for i in 0..8 {
        consistency(&render_frame(&cfg, 11, i), &mut c);
    }
    assert!(c.inside_fraction.len() >= 10, "too few instances checked: {}", c.inside_fraction.len());
    let worst = c.inside_fraction.iter().copied().fold(1.0, f64::min);
    (worst, median(&mut c.nocs_errors))
}

#[test]
fn rendered_ground_truth_is_self_consistent() {
    let (worst_noisy, med_noisy) = check_consistency(true);
    let (worst_clean, med_clean) = check_consistency(false);
    eprintln!(
        "inside: noisy {worst_noisy:.4} clean {worst_clean:.4}; NOCS median: noisy {med_noisy:.5} clean {med_clean:.5}"
    );
    assert!(worst_noisy >= 0.95, "noisy depth: only {worst_noisy} of an instance's points inside its box");
    assert!(worst_clean >= 0.99, "clean depth: only {worst_clean} of an instance's points inside its box");
    assert!(med_noisy < 0.02, "noisy NOCS median error {med_noisy}");
    assert!(med_clean < 2e-3, "clean NOCS median error {med_clean}");
    assert!(med_clean < med_noisy / 2.0, "noise-free depth should match the NOCS map much better");
}

#[test]
fn canonical_meshes_are_normalised_and_oriented() {
    for cat in Category::ALL {
        for seed in 0..25u64 {
            let m = generate_object(cat, &mut Rng::new(seed * 31 + cat.id() as u64));
            let b = m.mesh.aabb();
            let e = b.extents();
            assert!(b.center().norm() < 1e-6, "{cat} seed {seed}: box centre {:?}", b.center());
            assert!((e.norm() - 1.0).abs() < 1e-6, "{cat} seed {seed}: diagonal {}", e.norm());
            assert!((m.extents - e).norm() < 1e-9);
            assert!(e.y > 0.05 && e.x > 0.05 && e.z > 0.02, "{cat}: degenerate extents {e:?}");
            let size = m.size_m();
            assert!((size.iter().map(|v| v * v).sum::<f64>().sqrt() - m.scale).abs() < 1e-9);
            match cat {
                Category::Bottle | Category::Can | Category::Bowl => {
                    assert!((e.x - e.z).abs() < 1e-6, "{cat}: not symmetric about y: {e:?}");
                }
                _ => {}
            }
            let in_range = |v: f64, r: (f64, f64)| v >= r.0 - 1e-9 && v <= r.1 + 1e-9;
            use tricons::synth::shapes::{
                BOTTLE_HEIGHT_M, BOWL_DIAMETER_M, CAMERA_WIDTH_M, CAN_HEIGHT_M, LAPTOP_WIDTH_M, MUG_HEIGHT_M,
            };
            let ok = match cat {
                Category::Bottle => in_range(size[1], BOTTLE_HEIGHT_M),
                Category::Bowl => in_range(size[0], BOWL_DIAMETER_M),
                Category::Camera => in_range(size[0], CAMERA_WIDTH_M),
                Category::Can => in_range(size[1], CAN_HEIGHT_M),
                Category::Laptop => in_range(size[0], LAPTOP_WIDTH_M),
                Category::Mug => in_range(size[1], MUG_HEIGHT_M),
            };
            assert!(ok, "{cat}: metric size {size:?} out of range");
            let mesh = &m.mesh;
            let tri_center = |t: usize| {
                let [a, b, c] = mesh.triangles[t];
                (mesh.positions[a as usize] + mesh.positions[b as usize] + mesh.positions[c as usize]) / 3.0
            };
            match cat {
                Category::Mug => {
                    // handle points to +x
                    let handle: Vec<usize> =
                        (0..mesh.triangles.len()).filter(|&t| mesh.tags[t] == TAG_HANDLE).collect();
                    assert!(!handle.is_empty());
                    assert!(handle.iter().all(|&t| tri_center(t).x > 0.0), "mug handle not at +x");
                    assert!((b.max.x - e.x / 2.0).abs() < 1e-9 && e.x > e.z + 0.02, "handle should widen x");
                }
                Category::Camera => {
                    // lens glass (slot 2) faces +z, beyond the body
                    let glass: Vec<usize> = (0..mesh.triangles.len()).filter(|&t| mesh.materials[t] == 2).collect();
                    assert!(!glass.is_empty());
                    assert!(glass.iter().all(|&t| tri_center(t).z > 0.0), "camera lens not at +z");
                }
                Category::Laptop => {
                    // screen (slot 2) is behind the base's centre and above its top
                    let screen: Vec<usize> = (0..mesh.triangles.len()).filter(|&t| mesh.materials[t] == 2).collect();
                    let keys: Vec<usize> = (0..mesh.triangles.len()).filter(|&t| mesh.materials[t] == 1).collect();
                    let key_y = tri_center(keys[0]).y;
                    assert!((key_y - (b.min.y + 0.01)).abs() < 0.06, "keyboard deck should be at the bottom");
                    assert!(screen.iter().all(|&t| tri_center(t).y > key_y), "lid should rise above the base");
                    let base_z = keys.iter().map(|&t| tri_center(t).z).sum::<f64>() / keys.len() as f64;
                    assert!(screen.iter().all(|&t| tri_center(t).z < base_z), "lid should be at the back (-z)");
                }
                _ => {}
            }
        }
    }
}

#[test]
fn same_seed_same_frame_different_seed_different_frame() {
    let cfg = SynthConfig::default();
    let a = render_frame(&cfg, 3, 7);
    let b = render_frame(&cfg, 3, 7);
    assert!(a == b, "render_frame is not deterministic");
    let c = render_frame(&cfg, 4, 7);
    assert_ne!(a.frame.color.data, c.frame.color.data);
    let d = render_frame(&cfg, 3, 8);
    assert_ne!(a.frame.color.data, d.frame.color.data);
    assert!((a.frame.timestamp_s - 7.0 / 30.0).abs() < 1e-12);
}

#[test]
fn masks_and_annotations_agree_and_handles_can_hide() {
    let cfg = SynthConfig { min_objects: 4, max_objects: 6, ..SynthConfig::default() };
    let (mut hidden, mut shown) = (0, 0);
    let mut frames = 0;
    for i in 0..40u64 {
        let f = render_frame(&cfg, 5, i);
        frames += 1;
        let mask = f.annotations.mask.as_ref().expect("mask");
        let nocs = f.annotations.nocs.as_ref().expect("nocs");
        let n = f.annotations.instances.len();
        assert!(n >= 1, "frame {i} has no annotated instance");
        let mut counts = vec![0usize; 256];
        for (p, &l) in mask.data.iter().enumerate() {
            counts[usize::from(l)] += 1;
            if l == 0 {
                assert_eq!(&nocs.data[3 * p..3 * p + 3], &[0, 0, 0], "NOCS set outside the mask");
            }
        }
        for (k, inst) in f.annotations.instances.iter().enumerate() {
            assert_eq!(usize::from(inst.id), k + 1, "ids are 1..=n in order");
            assert!(counts[usize::from(inst.id)] >= MIN_VISIBLE_PX, "instance {} has too few pixels", inst.id);
            assert!(inst.validate().is_ok());
            if inst.class == Category::Mug {
                if inst.handle_visible { shown += 1 } else { hidden += 1 }
            } else {
                assert!(inst.handle_visible);
            }
        }
        assert!(counts[n + 1..].iter().all(|&c| c == 0), "frame {i}: mask holds an id that is not annotated");
        if hidden > 0 && shown > 0 && frames >= 10 {
            break;
        }
    }
    assert!(hidden > 0, "no mug with a hidden handle in {frames} frames");
    assert!(shown > 0, "no mug with a visible handle in {frames} frames");
}

fn read_all(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| {
            let e = e.expect("entry");
            (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).expect("read"))
        })
        .collect();
    files.sort();
    files
}

#[test]
fn generate_is_byte_identical_and_readable() {
    let cfg = SynthConfig {
        intrinsics: Intrinsics { width: 320, height: 240, fx: 295.5, fy: 295.1, cx: 161.3, cy: 122.1 },
        min_visible_px: 60,
        ..SynthConfig::default()
    };
    let frames = 5;
    let (a, b) = (tempfile::tempdir().expect("tmp"), tempfile::tempdir().expect("tmp"));
    let last = std::sync::atomic::AtomicUsize::new(0);
    let progress = |n: usize| last.store(n, std::sync::atomic::Ordering::SeqCst);
    let ma = generate(a.path(), &cfg, 9, frames, false, &progress).expect("generate a");
    assert_eq!(last.load(std::sync::atomic::Ordering::SeqCst), frames);
    let mb = generate(b.path(), &cfg, 9, frames, false, &|_| {}).expect("generate b");
    assert_eq!(ma, mb);
    assert_eq!(ma.source.as_deref(), Some("synthnocs seed=9 frames=5 generator=v1"));
    let (fa, fb) = (read_all(a.path()), read_all(b.path()));
    assert_eq!(fa.len(), 1 + frames * 5, "manifest + colour, depth, mask, coord, gt per frame");
    assert!(fa == fb, "generate is not byte-identical across runs");
    // refuses to overwrite unless asked
    assert!(generate(a.path(), &cfg, 9, 1, false, &|_| {}).is_err());

    let rec = open_recording(a.path()).expect("open");
    assert_eq!(rec.len(), frames);
    for i in 0..frames {
        assert_eq!(rec.frame_id(i), format!("{i:06}"));
        let want = render_frame(&cfg, 9, i as u64);
        let got = rec.read_frame(i).expect("frame");
        assert_eq!(got.color, want.frame.color);
        assert_eq!(got.depth.data, want.frame.depth.data);
        assert_eq!(got.intrinsics, cfg.intrinsics);
        assert!((got.timestamp_s - i as f64 / 30.0).abs() < 1e-12);
        let ann = rec.read_annotations(i).expect("gt").expect("annotated");
        assert_eq!(ann.instances, want.annotations.instances);
        assert_eq!(ann.mask, want.annotations.mask);
        assert_eq!(ann.nocs, want.annotations.nocs);
    }
    // a different seed gives different images
    let c = tempfile::tempdir().expect("tmp");
    generate(c.path(), &cfg, 10, 1, false, &|_| {}).expect("generate c");
    assert_ne!(
        std::fs::read(a.path().join("000000_color.png")).ok(),
        std::fs::read(c.path().join("000000_color.png")).ok()
    );
}

#[test]
fn distractor_masks_cover_visible_distractors_and_change_nothing_else() {
    let base = SynthConfig {
        intrinsics: Intrinsics { width: 320, height: 240, fx: 295.5, fy: 295.1, cx: 161.3, cy: 122.1 },
        min_visible_px: 60,
        max_distractors: 8,
        ..SynthConfig::default()
    };
    let cfg = SynthConfig { distractor_masks: true, ..base.clone() };
    let mut seen = 0;
    for i in 0..8u64 {
        let plain = render_frame(&base, 4, i);
        let f = render_frame(&cfg, 4, i);
        assert!(plain.distractors.is_none());
        assert_eq!(f.frame, plain.frame, "frame {i}: the distractor mask changed the images");
        assert_eq!(f.annotations, plain.annotations, "frame {i}: the distractor mask changed the annotations");
        let dis = f.distractors.expect("distractor mask asked for");
        let objects = f.annotations.mask.expect("mask");
        assert_eq!((dis.width, dis.height), (objects.width, objects.height));
        let mut counts = [0usize; 256];
        for (d, o) in dis.data.iter().zip(&objects.data) {
            counts[usize::from(*d)] += 1;
            assert!(*d == 0 || *o == 0, "frame {i}: a pixel is both an object and a distractor");
        }
        let n = counts[1..].iter().take_while(|&&c| c > 0).count();
        assert!(counts[n + 1..].iter().all(|&c| c == 0), "frame {i}: distractor ids are not 1..=n");
        assert!(counts[1..=n].iter().all(|&c| c >= cfg.min_visible_px), "frame {i}: a distractor below the floor");
        seen += n;
    }
    assert!(seen > 0, "no visible distractor in 8 frames of up to 8 each");

    // generate writes {id}_distractors.png beside byte-identical frame files
    let (a, b) = (tempfile::tempdir().expect("tmp"), tempfile::tempdir().expect("tmp"));
    generate(a.path(), &base, 4, 2, false, &|_| {}).expect("generate plain");
    generate(b.path(), &cfg, 4, 2, false, &|_| {}).expect("generate with distractor masks");
    let (fa, fb) = (read_all(a.path()), read_all(b.path()));
    let without: Vec<_> = fb.iter().filter(|(n, _)| !n.ends_with("_distractors.png")).cloned().collect();
    assert!(fa == without, "the other files differ");
    assert_eq!(fb.len(), fa.len() + 2);
    for i in 0..2u64 {
        let path = b.path().join(format!("{i:06}_distractors.png"));
        let got = read_label_png(&path, SizeLimit::like(320, 240, "test")).expect("read");
        assert_eq!(Some(got), render_frame(&cfg, 4, i).distractors);
    }
}
