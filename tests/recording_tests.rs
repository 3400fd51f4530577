//! Recording format and NOCS layout: round trips, crash safety, bad input.

use std::fs;
use std::path::Path;
use tricons::frame::DEPTH_SCALE_MM;
use tricons::geometry::{Vec3, rotation_axis_angle};
use tricons::image_io::{encode_png, write_color_png, write_depth_png, write_label_png};
use tricons::recording::{
    FrameAnnotations, GtInstance, Manifest, Recording, RecordingWriter, TriconsRecording, WriteMode, open_recording,
};
use tricons::{Category, ColorImage, DepthImage, Error, Intrinsics, LabelImage, NocsMap, Pose, RgbdFrame};

const W: u32 = 32;
const H: u32 = 24;

fn small_intrinsics() -> Intrinsics {
    Intrinsics { width: W, height: H, fx: 30.0, fy: 30.0, cx: 15.5, cy: 11.5 }
}

fn frame(seed: u16) -> RgbdFrame {
    let mut color = ColorImage::new(W, H);
    color.data.iter_mut().enumerate().for_each(|(i, v)| *v = (i as u16).wrapping_mul(seed) as u8);
    let mut depth = DepthImage::new(W, H, DEPTH_SCALE_MM);
    depth.data.iter_mut().enumerate().for_each(|(i, v)| *v = 500 + (i as u16 % 97) * seed);
    RgbdFrame { color, depth, intrinsics: small_intrinsics(), timestamp_s: f64::from(seed) / 30.0 }
}

fn annotations() -> FrameAnnotations {
    let mut mask = LabelImage::new(W, H);
    mask.data[40..60].fill(1);
    let mut nocs = NocsMap::new(W, H);
    nocs.data[120..180].fill(30000);
    FrameAnnotations {
        instances: vec![GtInstance {
            id: 1,
            class: Category::Mug,
            camera_from_object: Pose::new(rotation_axis_angle(&Vec3::y(), 0.4), Vec3::new(0.01, 0.02, 0.6)),
            size_m: [0.12, 0.1, 0.09],
            handle_visible: false,
        }],
        mask: Some(mask),
        nocs: Some(nocs),
    }
}

fn write_recording(dir: &Path, n: u16) {
    let mut w =
        RecordingWriter::create(dir, Manifest::new(small_intrinsics(), DEPTH_SCALE_MM), WriteMode::New).unwrap();
    for i in 0..n {
        let ann = (i % 2 == 0).then(annotations);
        w.write_frame(&format!("{i:06}"), &frame(i + 1), ann.as_ref()).unwrap();
    }
    w.finish().unwrap();
}

fn err_text(e: Error) -> String {
    e.to_string()
}

#[test]
fn writer_and_reader_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 3);
    let rec = open_recording(dir.path()).unwrap();
    assert_eq!(rec.len(), 3);
    assert_eq!(rec.frame_id(2), "000002");
    for i in 0..3 {
        assert_eq!(rec.read_frame(i).unwrap(), frame(i as u16 + 1));
    }
    assert_eq!(rec.read_annotations(0).unwrap(), Some(annotations()));
    assert_eq!(rec.read_annotations(1).unwrap(), None);
    assert_eq!(rec.read_instances(2).unwrap(), Some(annotations().instances));
}

#[test]
fn writer_refuses_to_clobber_a_recording() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 1);
    let m = Manifest::new(small_intrinsics(), DEPTH_SCALE_MM);
    let err = RecordingWriter::create(dir.path(), m.clone(), WriteMode::New).err().unwrap();
    assert!(err_text(err).contains("not empty"));
    assert!(RecordingWriter::create(dir.path(), m, WriteMode::Overwrite).is_ok());
}

#[test]
fn a_killed_writer_leaves_only_complete_frames_listed() {
    let dir = tempfile::tempdir().unwrap();
    let mut w =
        RecordingWriter::create(dir.path(), Manifest::new(small_intrinsics(), DEPTH_SCALE_MM), WriteMode::New).unwrap();
    w.write_frame("000000", &frame(1), None).unwrap();
    w.flush().unwrap();
    // Simulate a kill mid-frame: a temporary file exists, the frame is not listed.
    fs::write(dir.path().join("000001_color.png.tmp999"), b"half a png").unwrap();
    drop(w);
    let rec = TriconsRecording::open(dir.path()).unwrap();
    assert_eq!(rec.len(), 1);
    assert_eq!(rec.read_frame(0).unwrap(), frame(1));
}

/// A non-empty directory is refused for a new recording; appending keeps every frame and
/// file already there, continues the numbering after what is on disk, refuses another
/// camera, and never writes a listed frame again.
#[test]
fn new_recordings_need_an_empty_directory_and_append_never_overwrites() {
    let dir = tempfile::tempdir().unwrap();
    fs::write(dir.path().join("notes.txt"), b"mine").unwrap();
    let err = err_text(
        RecordingWriter::create(dir.path(), Manifest::new(small_intrinsics(), DEPTH_SCALE_MM), WriteMode::New)
            .err()
            .unwrap(),
    );
    assert!(err.contains("not empty") && err.contains("notes.txt"), "{err}");
    assert!(
        RecordingWriter::create(dir.path(), Manifest::new(small_intrinsics(), DEPTH_SCALE_MM), WriteMode::Append)
            .is_err()
    );

    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 2);
    let before = fs::read(dir.path().join("000001_color.png")).unwrap();
    // an unlisted frame's files (a writer killed before its manifest flush) count as taken
    fs::write(dir.path().join("000005_color.png"), b"orphan").unwrap();
    let mut w =
        RecordingWriter::create(dir.path(), Manifest::new(small_intrinsics(), DEPTH_SCALE_MM), WriteMode::Append)
            .unwrap();
    assert_eq!((w.len(), w.next_numeric_id().unwrap()), (2, 6));
    let err = err_text(w.write_frame("000001", &frame(9), None).unwrap_err());
    assert!(err.contains("already in the recording"), "{err}");
    w.write_frame("000006", &frame(7), None).unwrap();
    w.finish().unwrap();
    let rec = TriconsRecording::open(dir.path()).unwrap();
    assert_eq!(rec.len(), 3);
    assert_eq!(rec.read_frame(1).unwrap(), frame(2));
    assert_eq!(rec.read_frame(2).unwrap(), frame(7));
    assert_eq!(fs::read(dir.path().join("000001_color.png")).unwrap(), before);
    assert_eq!(fs::read(dir.path().join("000005_color.png")).unwrap(), b"orphan");

    let mut other = small_intrinsics();
    other.fx += 1.0;
    let err = err_text(
        RecordingWriter::create(dir.path(), Manifest::new(other, DEPTH_SCALE_MM), WriteMode::Append).err().unwrap(),
    );
    assert!(err.contains("another camera"), "{err}");
}

/// Temporary files of a killed writer (`*.tmp<pid>` of a process that is gone) are removed
/// when the next writer opens the directory; a live process's are kept.
#[test]
fn a_killed_writers_temporaries_are_cleaned_at_the_next_open() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 1);
    // pid 2^22 + 1 is above Linux's pid_max limit: never a live process
    for name in ["000001_color.png.tmp4194305", "manifest.json.tmp4194305"] {
        fs::write(dir.path().join(name), b"half").unwrap();
    }
    let mine = format!("000002_color.png.tmp{}", std::process::id());
    fs::write(dir.path().join(&mine), b"in progress").unwrap();
    let w = RecordingWriter::create(dir.path(), Manifest::new(small_intrinsics(), DEPTH_SCALE_MM), WriteMode::Append)
        .unwrap();
    drop(w);
    let mut left: Vec<String> = fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.contains(".tmp"))
        .collect();
    left.sort();
    assert_eq!(left, vec![mine]);
    assert_eq!(TriconsRecording::open(dir.path()).unwrap().len(), 1);
}

#[test]
fn missing_directory_and_missing_files_name_the_path() {
    let err = err_text(open_recording(Path::new("/nonexistent/rec")).err().unwrap());
    assert!(err.contains("/nonexistent/rec"), "{err}");

    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 2);
    fs::remove_file(dir.path().join("000001_depth.png")).unwrap();
    let rec = open_recording(dir.path()).unwrap();
    let err = err_text(rec.read_frame(1).unwrap_err());
    assert!(err.contains("000001_depth.png"), "{err}");
}

#[test]
fn corrupt_png_and_eight_bit_depth_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 2);
    let color = dir.path().join("000000_color.png");
    let bytes = fs::read(&color).unwrap();
    fs::write(&color, &bytes[..bytes.len() / 3]).unwrap();
    let rec = open_recording(dir.path()).unwrap();
    let err = err_text(rec.read_frame(0).unwrap_err());
    assert!(err.contains("000000_color.png"), "{err}");

    let depth8 = encode_png(W, H, png::ColorType::Grayscale, png::BitDepth::Eight, &[9; (W * H) as usize]).unwrap();
    fs::write(dir.path().join("000001_depth.png"), depth8).unwrap();
    let err = err_text(rec.read_frame(1).unwrap_err());
    assert!(err.contains("000001_depth.png") && err.contains("16-bit"), "{err}");
}

#[test]
fn image_size_must_match_the_manifest() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 1);
    write_color_png(&dir.path().join("000000_color.png"), &ColorImage::new(W + 1, H)).unwrap();
    let err = err_text(open_recording(dir.path()).unwrap().read_frame(0).unwrap_err());
    assert!(err.contains("000000_color.png") && err.contains("33x24"), "{err}");
}

/// A header declaring 60000 x 60000 16-bit RGBA pixels (28.8 GB decoded), no pixel data.
fn size_bomb() -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, 60_000, 60_000);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Sixteen);
    let mut writer = encoder.write_header().unwrap();
    writer.write_chunk(png::chunk::IDAT, &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]).unwrap();
    drop(writer);
    out
}

/// Every image of a frame is checked against the manifest's size before it is decoded:
/// a PNG size bomb is a clear error naming the file, not an allocation abort.
#[test]
fn png_size_bombs_are_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 1);
    for name in ["000000_color.png", "000000_depth.png", "000000_mask.png", "000000_coord.png"] {
        let path = dir.path().join(name);
        let good = fs::read(&path).unwrap();
        fs::write(&path, size_bomb()).unwrap();
        let rec = open_recording(dir.path()).unwrap();
        let err = if name.contains("color") || name.contains("depth") {
            err_text(rec.read_frame(0).unwrap_err())
        } else {
            err_text(rec.read_annotations(0).unwrap_err())
        };
        assert!(err.contains(name) && err.contains("60000x60000") && err.contains("32x24 as in the manifest"), "{err}");
        fs::write(&path, good).unwrap();
    }
}

/// An annotations file may only name images inside the recording (it once opened /etc/passwd).
#[test]
fn annotation_images_outside_the_recording_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 1);
    let gt = dir.path().join("000000_gt.json");
    let text = fs::read_to_string(&gt).unwrap();
    for (field, bad) in [("mask", "/etc/passwd"), ("mask", "../000000_mask.png"), ("nocs", "sub/../../x.png")] {
        let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
        v[field] = serde_json::Value::from(bad);
        fs::write(&gt, serde_json::to_string(&v).unwrap()).unwrap();
        let err = err_text(open_recording(dir.path()).unwrap().read_annotations(0).unwrap_err());
        assert!(
            err.contains("000000_gt.json") && err.contains(&format!("field {field}")) && err.contains(bad),
            "{err}"
        );
    }
}

#[test]
fn malformed_manifest_and_annotations_name_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    write_recording(dir.path(), 1);
    let manifest = dir.path().join("manifest.json");
    let good = fs::read_to_string(&manifest).unwrap();

    fs::write(&manifest, "{ not json").unwrap();
    assert!(err_text(open_recording(dir.path()).err().unwrap()).contains("manifest.json"));

    fs::write(&manifest, good.replace("\"version\": 1", "\"version\": 7")).unwrap();
    let err = err_text(open_recording(dir.path()).err().unwrap());
    assert!(err.contains("version 7") && err.contains("manifest.json"), "{err}");

    fs::write(&manifest, good.replace("\"depth_scale_m\": 0.001", "\"depth_scale_m\": -1.0")).unwrap();
    assert!(err_text(open_recording(dir.path()).err().unwrap()).contains("depth_scale_m"));

    fs::write(&manifest, good.replace("\"fx\": 30.0", "\"fx\": \"wide\"")).unwrap();
    let err = err_text(open_recording(dir.path()).err().unwrap());
    assert!(err.contains("manifest.json") && err.contains("field intrinsics.fx"), "{err}");

    // serde's type errors name the field too
    fs::write(&manifest, good.replace("\"version\": 1", "\"version\": \"1\"")).unwrap();
    let err = err_text(open_recording(dir.path()).err().unwrap());
    assert!(err.contains("field version") && err.contains("expected u32"), "{err}");
    fs::write(&manifest, good.replace("\"height\": 24", "\"height\": -24")).unwrap();
    let err = err_text(open_recording(dir.path()).err().unwrap());
    assert!(err.contains("field intrinsics.height") && err.contains("-24"), "{err}");

    fs::write(&manifest, &good).unwrap();
    let gt = dir.path().join("000000_gt.json");
    let gt_text = fs::read_to_string(&gt).unwrap();
    fs::write(&gt, gt_text.replace("\"mug\"", "\"chair\"")).unwrap();
    let err = err_text(open_recording(dir.path()).unwrap().read_instances(0).unwrap_err());
    assert!(err.contains("000000_gt.json") && err.contains("chair"), "{err}");

    fs::write(&gt, gt_text.replace("\"s\": [\n        0.12", "\"s\": [\n        -0.12")).unwrap();
    let err = err_text(open_recording(dir.path()).unwrap().read_instances(0).unwrap_err());
    assert!(err.contains("000000_gt.json") && err.contains("field s"), "{err}");
}

/// Writes a one-frame NOCS-layout scene with a box-shaped object seen face-on
/// at a known similarity transform; returns (pose, size).
fn write_nocs_scene(dir: &Path) -> (Pose, [f64; 3]) {
    let k = Intrinsics::REAL275;
    let rotation = rotation_axis_angle(&Vec3::new(0.3, 1.0, 0.2), 0.5);
    let pose = Pose::new(rotation, Vec3::new(0.02, -0.01, 0.7));
    let size = [0.16, 0.1, 0.12];
    let diag = size.iter().map(|v| v * v).sum::<f64>().sqrt();
    let (w, h) = (k.width, k.height);
    let mut color = ColorImage::new(w, h);
    color.data.fill(90);
    let mut depth = DepthImage::new(w, h, DEPTH_SCALE_MM);
    let mut mask = vec![255u8; (w * h) as usize];
    let mut coord = vec![0u8; (w * h * 3) as usize];
    // Sample the object's front face (z = +size/2), project, splat.
    let steps = 200;
    for a in 0..=steps {
        for b in 0..=steps {
            let p_obj = Vec3::new(
                (a as f64 / steps as f64 - 0.5) * size[0],
                (b as f64 / steps as f64 - 0.5) * size[1],
                -size[2] / 2.0,
            );
            let p_cam = pose.transform_point(&p_obj);
            let (u, v) = k.project(&p_cam);
            let (u, v) = (u.round() as u32, v.round() as u32);
            let i = (v * w + u) as usize;
            depth.data[i] = (p_cam.z * 1000.0).round() as u16;
            mask[i] = 3;
            let n = p_obj / diag + Vec3::repeat(0.5);
            coord[i * 3] = (n.x * 255.0).round() as u8;
            coord[i * 3 + 1] = (n.y * 255.0).round() as u8;
            coord[i * 3 + 2] = ((1.0 - n.z) * 255.0).round() as u8; // stored flipped
        }
    }
    write_color_png(&dir.join("0000_color.png"), &color).unwrap();
    write_depth_png(&dir.join("0000_depth.png"), &depth).unwrap();
    write_label_png(&dir.join("0000_mask.png"), &LabelImage { width: w, height: h, data: mask }).unwrap();
    fs::write(dir.join("0000_coord.png"), encode_png(w, h, png::ColorType::Rgb, png::BitDepth::Eight, &coord).unwrap())
        .unwrap();
    fs::write(dir.join("0000_meta.txt"), "3 3 camera_canon_norm\n5 0 distractor\n").unwrap();
    (pose, size)
}

#[test]
fn nocs_layout_recovers_the_pose_from_nocs_map_and_depth() {
    let dir = tempfile::tempdir().unwrap();
    let (pose, size) = write_nocs_scene(dir.path());
    let rec = open_recording(dir.path()).unwrap();
    assert!(rec.describe().contains("NOCS layout"));
    assert_eq!(rec.len(), 1);
    assert_eq!(rec.frame_id(0), "0000");
    assert_eq!(rec.intrinsics(), Intrinsics::REAL275);
    let frame = rec.read_frame(0).unwrap();
    assert_eq!(frame.depth.depth_scale_m, DEPTH_SCALE_MM);
    let ann = rec.read_annotations(0).unwrap().unwrap();
    assert_eq!(ann.instances.len(), 1);
    let g = &ann.instances[0];
    assert_eq!((g.id, g.class), (3, Category::Camera));
    let angle = tricons::geometry::rotation_angle_deg(&g.camera_from_object.rotation, &pose.rotation);
    assert!(angle < 1.0, "rotation off by {angle} deg");
    assert!((g.camera_from_object.translation_m - pose.translation_m).norm() < 0.005);
    // Only the front face is seen: x and y extents are recovered, z is not.
    assert!((g.size_m[0] - size[0]).abs() < 0.005 && (g.size_m[1] - size[1]).abs() < 0.005, "{:?}", g.size_m);
    let mask = ann.mask.unwrap();
    assert!(mask.data.iter().all(|&l| l == 0 || l == 3));
}

/// CAMERA25 as SPD / AG-Pose keep it: `camera/val/00000/` (any case) with the composed
/// depth in `camera_full_depths/val/00000/`; its `_depth.png` (objects only) is not read,
/// 32001 is no depth, and a missing composed file is an error naming it.
#[test]
fn nocs_layout_camera_scenes_read_the_composed_depth() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("NOCS/camera/val/00000");
    fs::create_dir_all(&scene).unwrap();
    write_nocs_scene(&scene);
    let depth = tricons::image_io::read_png(&scene.join("0000_depth.png"), tricons::image_io::SizeLimit::Capped)
        .unwrap()
        .samples_u16();
    let mut composed: Vec<u8> = depth.iter().flat_map(|&d| [(d & 0xFF) as u8, (d >> 8) as u8, 0]).collect();
    composed[..3].copy_from_slice(&[(32001 & 0xFF) as u8, (32001 >> 8) as u8, 0]);
    let full = dir.path().join("NOCS/camera_full_depths/val/00000");
    fs::create_dir_all(&full).unwrap();
    fs::write(
        full.join("0000_composed.png"),
        encode_png(640, 480, png::ColorType::Rgb, png::BitDepth::Eight, &composed).unwrap(),
    )
    .unwrap();
    // the objects-only _depth.png of CAMERA: zero everywhere here, so reading it would show
    write_depth_png(&scene.join("0000_depth.png"), &DepthImage::new(640, 480, DEPTH_SCALE_MM)).unwrap();
    let rec = open_recording(&scene).unwrap();
    assert_eq!(rec.intrinsics(), Intrinsics::CAMERA25);
    let frame = rec.read_frame(0).unwrap();
    assert_eq!(frame.depth.data[0], 0, "32001 is no depth");
    assert_eq!(frame.depth.data[1..], depth[1..]);
    fs::remove_file(full.join("0000_composed.png")).unwrap();
    let err = err_text(rec.read_frame(0).unwrap_err());
    assert!(
        err.contains("camera_full_depths/val/00000/0000_composed.png") && err.contains("rendered objects only"),
        "{err}"
    );
}

#[test]
fn nocs_layout_bad_meta_and_depth_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    write_nocs_scene(dir.path());
    fs::write(dir.path().join("0000_meta.txt"), "3 3 camera\nthree 3 camera\n").unwrap();
    let rec = open_recording(dir.path()).unwrap();
    let err = err_text(rec.read_annotations(0).unwrap_err());
    assert!(err.contains("0000_meta.txt line 2"), "{err}");
    fs::write(dir.path().join("0000_meta.txt"), "3 9 spaceship\n").unwrap();
    assert!(err_text(rec.read_annotations(0).unwrap_err()).contains("class_id"));

    fs::write(dir.path().join("0000_meta.txt"), "3 3 camera\n").unwrap();
    write_label_png(&dir.path().join("0000_mask.png"), &LabelImage::new(320, 240)).unwrap();
    let err = err_text(rec.read_annotations(0).unwrap_err());
    assert!(err.contains("0000_mask.png") && err.contains("320x240"), "{err}");

    let depth8 = encode_png(640, 480, png::ColorType::Grayscale, png::BitDepth::Eight, &vec![1; 640 * 480]).unwrap();
    fs::write(dir.path().join("0000_depth.png"), depth8).unwrap();
    let err = err_text(rec.read_frame(0).unwrap_err());
    assert!(err.contains("0000_depth.png") && err.contains("16-bit"), "{err}");
}

#[test]
fn a_directory_that_is_neither_layout_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    fs::write(dir.path().join("notes.txt"), "hello").unwrap();
    let err = err_text(open_recording(dir.path()).err().unwrap());
    assert!(err.contains("neither a tricons recording"), "{err}");
}

/// ROS 2 bags (MCAP) read as recordings: bags written here with the `mcap` crate's writer and
/// tricons' CDR encoder (the Python writer's bags are checked in tools/tests/test_ros2.py).
#[cfg(feature = "ros2")]
mod ros2_bags {
    use super::*;
    use std::borrow::Cow;
    use std::collections::BTreeMap;
    use tricons::recording::{BagTopics, McapBag, open_recording_with};
    use tricons::ros2::msg::{CameraInfo, Header, Image, Time};
    use tricons::ros2::{cdr, schema};

    /// The input the `ros2_bag` fuzz target found (a record overrunning its uncompressed
    /// chunk makes mcap 0.26's reader subtract past zero): an error naming the bag, no panic.
    /// With overflow checks (debug, CI) the reader panics and the panic becomes the error;
    /// without (release) the count wraps and the reader reports an early end: "MCAP" in both.
    #[test]
    fn a_record_overrunning_its_chunk_is_an_error_not_a_panic() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fuzz/regressions/ros2_bag/record-overruns-uncompressed-chunk.mcap");
        let topics =
            BagTopics { color: "/c".into(), depth: "/d".into(), camera_info: "/i".into(), ..BagTopics::default() };
        let Err(err) = McapBag::open(&path, &topics) else { panic!("a malformed bag opened") };
        let msg = err.to_string();
        assert!(msg.contains("record-overruns-uncompressed-chunk.mcap") && msg.contains("MCAP"), "{msg}");
    }

    const BW: u32 = 8;
    const BH: u32 = 6;

    /// A message to write: topic, schema, stamp (s), payload.
    struct Msg {
        topic: &'static str,
        schema: (&'static str, &'static str),
        payload: Vec<u8>,
    }

    fn header(t: f64) -> Header {
        Header { stamp: Time::from_seconds(t), frame_id: "cam_optical".into() }
    }

    fn image(t: f64, encoding: &str, bytes_per_px: u32, data: Vec<u8>) -> Vec<u8> {
        let img = Image {
            header: header(t),
            height: BH,
            width: BW,
            encoding: encoding.into(),
            is_bigendian: 0,
            step: BW * bytes_per_px,
            data: Cow::Owned(data),
        };
        cdr::encode(&img).unwrap()
    }

    fn rgb_pixels(seed: u8) -> Vec<u8> {
        (0..BW * BH * 3).map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed)).collect()
    }

    fn depth_mm(seed: u16) -> Vec<u16> {
        (0..BW * BH).map(|i| 400 + i as u16 * 3 + seed).collect()
    }

    fn color_msg(t: f64, seed: u8) -> Msg {
        Msg { topic: "/c", schema: schema::IMAGE, payload: image(t, "rgb8", 3, rgb_pixels(seed)) }
    }

    fn depth_msg(t: f64, seed: u16) -> Msg {
        let data = depth_mm(seed).iter().flat_map(|v| v.to_le_bytes()).collect();
        Msg { topic: "/d", schema: schema::IMAGE, payload: image(t, "16UC1", 2, data) }
    }

    fn info_msg(t: f64) -> Msg {
        let info = CameraInfo {
            header: header(t),
            height: BH,
            width: BW,
            distortion_model: "plumb_bob".into(),
            d: vec![0.0; 5],
            k: [6.0, 0.0, 3.5, 0.0, 6.5, 2.5, 0.0, 0.0, 1.0],
            ..CameraInfo::default()
        };
        Msg { topic: "/i", schema: schema::CAMERA_INFO, payload: cdr::encode(&info).unwrap() }
    }

    fn topics() -> BagTopics {
        BagTopics { color: "/c".into(), depth: "/d".into(), camera_info: "/i".into(), ..BagTopics::default() }
    }

    fn write_bag(path: &Path, messages: &[Msg]) {
        let file = std::io::BufWriter::new(fs::File::create(path).unwrap());
        let mut w = mcap::WriteOptions::new().profile("ros2").create(file).unwrap();
        let mut channels: BTreeMap<&str, u16> = BTreeMap::new();
        for (seq, m) in messages.iter().enumerate() {
            let id = match channels.get(m.topic) {
                Some(&id) => id,
                None => {
                    let s = w.add_schema(m.schema.0, "ros2msg", m.schema.1.as_bytes()).unwrap();
                    let id = w.add_channel(s, m.topic, "cdr", &BTreeMap::new()).unwrap();
                    channels.insert(m.topic, id);
                    id
                }
            };
            let header = mcap::records::MessageHeader {
                channel_id: id,
                sequence: seq as u32,
                log_time: seq as u64,
                publish_time: seq as u64,
            };
            w.write_to_known_channel(&header, &m.payload).unwrap();
        }
        w.finish().unwrap();
    }

    fn open_err(path: &Path) -> String {
        match open_recording_with(path, &topics()) {
            Ok(_) => panic!("{} opened", path.display()),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_bag_reads_as_frames_paired_by_stamp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("b.mcap");
        // colour all first, then depth (one 4 ms late, one without a partner), then info
        let messages = vec![
            color_msg(10.0, 1),
            color_msg(10.1, 2),
            color_msg(10.2, 3),
            depth_msg(10.004, 1),
            depth_msg(10.1, 2),
            depth_msg(10.15, 9),
            depth_msg(10.2, 3),
            info_msg(10.0),
        ];
        write_bag(&path, &messages);
        let rec = open_recording_with(&path, &topics()).unwrap();
        assert_eq!(rec.len(), 3);
        assert_eq!(rec.camera_frame_id(), Some("cam_optical"));
        assert_eq!(rec.intrinsics(), Intrinsics { width: BW, height: BH, fx: 6.0, fy: 6.5, cx: 3.5, cy: 2.5 });
        // backwards and forwards: every frame is its own colour and depth
        for i in [2usize, 0, 1, 2, 1] {
            let f = rec.read_frame(i).unwrap();
            assert_eq!(rec.frame_id(i), format!("{i:06}"));
            assert_eq!(f.color.data, rgb_pixels(i as u8 + 1));
            assert_eq!(f.depth.data, depth_mm(i as u16 + 1));
            assert_eq!(f.depth.depth_scale_m, DEPTH_SCALE_MM);
            assert!((f.timestamp_s - (10.0 + 0.1 * i as f64)).abs() < 1e-9);
            assert_eq!(rec.timestamp_s(i), Some(f.timestamp_s));
        }
        let bag = McapBag::open(&path, &topics()).unwrap();
        assert_eq!(bag.unpaired(), (0, 1));
    }

    #[test]
    fn colour_and_depth_encodings_convert_exactly() {
        let dir = tempfile::tempdir().unwrap();
        let rgb = rgb_pixels(5);
        let bgr: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
        let bgra: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[2], p[1], p[0], 255]).collect();
        let metres: Vec<f32> = (0..BW * BH)
            .map(|i| match i {
                0 => f32::NAN,
                1 => -1.0,
                2 => 70.0,
                3 => 1.2344,
                _ => 0.5 + i as f32 * 0.001,
            })
            .collect();
        let f32_bytes: Vec<u8> = metres.iter().flat_map(|v| v.to_le_bytes()).collect();
        for (encoding, bpp, data) in [("bgr8", 3, bgr), ("bgra8", 4, bgra)] {
            let path = dir.path().join(format!("{encoding}.mcap"));
            let color = Msg { topic: "/c", schema: schema::IMAGE, payload: image(1.0, encoding, bpp, data) };
            let depth = Msg { topic: "/d", schema: schema::IMAGE, payload: image(1.0, "32FC1", 4, f32_bytes.clone()) };
            write_bag(&path, &[info_msg(1.0), color, depth]);
            let f = open_recording_with(&path, &topics()).unwrap().read_frame(0).unwrap();
            assert_eq!(f.color.data, rgb, "{encoding}");
            assert_eq!(&f.depth.data[..4], &[0, 0, 0, 1234]);
            for (i, mm) in f.depth.data.iter().enumerate().skip(4) {
                assert_eq!(*mm, (500 + i) as u16);
            }
        }
    }

    #[test]
    fn bad_bags_are_errors_naming_the_file_and_topic() {
        let dir = tempfile::tempdir().unwrap();
        let p = |name: &str| dir.path().join(name);
        // not an MCAP file
        fs::write(p("junk.mcap"), b"SQLite format 3\0 not a bag").unwrap();
        let e = open_err(&p("junk.mcap"));
        assert!(e.contains("junk.mcap") && e.contains("not an MCAP file"), "{e}");
        // no camera info: the topics it has are listed
        write_bag(&p("noinfo.mcap"), &[color_msg(1.0, 1), depth_msg(1.0, 1)]);
        let e = open_err(&p("noinfo.mcap"));
        assert!(e.contains("no messages on /i") && e.contains("--camera-info-topic"), "{e}");
        assert!(e.contains("/c (sensor_msgs/msg/Image, 1 messages)"), "{e}");
        // a CameraInfo on the depth topic
        let wrong = Msg { topic: "/d", ..info_msg(1.0) };
        write_bag(&p("wrong.mcap"), &[info_msg(1.0), color_msg(1.0, 1), wrong]);
        let e = open_err(&p("wrong.mcap"));
        assert!(e.contains("topic /d carries \"sensor_msgs/msg/CameraInfo\""), "{e}");
        // an encoding tricons does not read: opens, the frame is an error naming topic and encoding
        let yuv = Msg { topic: "/c", schema: schema::IMAGE, payload: image(1.0, "yuv422", 2, vec![0; 96]) };
        write_bag(&p("yuv.mcap"), &[info_msg(1.0), yuv, depth_msg(1.0, 1)]);
        let e = open_recording_with(&p("yuv.mcap"), &topics()).unwrap().read_frame(0).unwrap_err().to_string();
        assert!(e.contains("yuv.mcap") && e.contains("(/c)") && e.contains("\"yuv422\""), "{e}");
        // depth of another size than colour: not aligned
        let mut small = depth_msg(1.0, 1);
        let img = Image { width: 4, height: 3, step: 8, data: Cow::Owned(vec![0; 24]), ..Image::default() };
        small.payload = cdr::encode(&Image { header: header(1.0), encoding: "16UC1".into(), ..img }).unwrap();
        write_bag(&p("unaligned.mcap"), &[info_msg(1.0), color_msg(1.0, 1), small]);
        let e = open_recording_with(&p("unaligned.mcap"), &topics()).unwrap().read_frame(0).unwrap_err().to_string();
        assert!(e.contains("4x3") && e.contains("aligned to colour"), "{e}");
        // a payload that is not the message its schema says
        let garbage = Msg { topic: "/c", schema: schema::IMAGE, payload: vec![0, 1, 0, 0, 9] };
        write_bag(&p("garbage.mcap"), &[info_msg(1.0), garbage, depth_msg(1.0, 1)]);
        let e = open_err(&p("garbage.mcap"));
        assert!(e.contains("topic /c message 1") && e.contains("not the expected message"), "{e}");
        // truncated inside the data: an error, whatever the cut
        write_bag(&p("whole.mcap"), &[info_msg(1.0), color_msg(1.0, 1), depth_msg(1.0, 1)]);
        let whole = fs::read(p("whole.mcap")).unwrap();
        for cut in [9, whole.len() / 3, whole.len() / 2, whole.len() - 9] {
            fs::write(p("cut.mcap"), &whole[..cut]).unwrap();
            let e = open_err(&p("cut.mcap"));
            assert!(e.contains("cut.mcap"), "{e}");
        }
    }

    /// What the MCAP sink writes decodes back to the messages of the JSON Lines result, and
    /// the file appears only when complete.
    #[test]
    fn the_mcap_sink_writes_a_complete_bag_on_close() {
        use tricons::output::mcap_sink::{DETECTIONS_TOPIC, McapSink, OVERLAY_TOPIC};
        use tricons::output::sink::Sink;
        use tricons::output::{FramePredictions, PredInstance};
        use tricons::ros2::convert;
        use tricons::ros2::msg::Detection3DArray;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out/results.mcap");
        let mut sink = McapSink::create(&path, "cam").unwrap();
        let inst = PredInstance {
            class: Category::Laptop,
            score: 0.5,
            camera_from_object: Pose::new(
                rotation_axis_angle(&Vec3::new(0.0, 1.0, 0.0), 0.3),
                Vec3::new(0.0, 0.1, 0.7),
            ),
            size_m: [0.3, 0.2, 0.25],
            box2d: None,
            mask: None,
        };
        let frames: Vec<FramePredictions> = (0..3)
            .map(|i| FramePredictions {
                frame: format!("{i:06}"),
                timestamp_s: Some(100.0 + f64::from(i)),
                instances: vec![inst.clone(); i as usize],
            })
            .collect();
        for f in &frames {
            sink.publish_with_image(f, "", &frame(3)).unwrap();
        }
        sink.flush().unwrap();
        assert!(!path.exists(), "the bag appears only when complete");
        sink.close().unwrap();
        let bytes = fs::read(&path).unwrap();
        assert!(!dir.path().join("out/results.mcap.part").exists());
        let mut seen = 0;
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            let i = (m.log_time / 1_000_000_000 - 100) as usize;
            if m.channel.topic == DETECTIONS_TOPIC {
                let msg: Detection3DArray = cdr::decode(&m.data, "test").unwrap();
                assert_eq!(msg, convert::detections(&frames[i], "cam"));
                seen += 1;
            } else if m.channel.topic == OVERLAY_TOPIC {
                let img: Image = cdr::decode(&m.data, "test").unwrap();
                assert_eq!((img.width, img.height, img.data.len()), (W, H, (W * H * 3) as usize));
            }
        }
        assert_eq!(seen, 3);
    }
}
