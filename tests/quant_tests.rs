//! int8 quantization: the fused layers against exact integer references and the
//! float layers, the profile and its load-time rewrite, determinism, and the
//! user-facing `tricons quantize` / `tricons validate` paths with their errors.

mod common;

use std::fs;
use std::path::Path;

use common::cli::{assert_clean_failure, demo_subset, repo, stderr, tricons};
use tricons::ops::qconv::{ConvGeometry, ConvLayer, PatchOrder, qconv, qconv_reference};
use tricons::pose::PoseEstimator;
use tricons::quant::calibrate::{ProfileTarget, QuantizeOptions, build_profile};
use tricons::quant::params::TensorStats;
use tricons::quant::profile::CalibrationInfo;
use tricons::quant::{Int8Layer, LayerInput, LayerOutput, ModelKind, OutputFold, QParams, QuantProfile};
use tricons::recording::open_recording;

/// Deterministic values in [-1, 1).
fn values(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        })
        .collect()
}

struct LinearCase {
    k: usize,
    n: usize,
    w: Vec<f32>,
    post: Vec<f32>,
    bias: Vec<f32>,
    input: QParams,
}

fn case(k: usize, n: usize, seed: u64) -> LinearCase {
    LinearCase {
        k,
        n,
        w: values(k * n, seed),
        post: values(n, seed + 1).iter().map(|v| 0.5 + v.abs()).collect(),
        bias: values(n, seed + 2),
        input: QParams::from_range(-1.0, 2.0),
    }
}

impl LinearCase {
    fn layer(&self, relu: bool, output: Option<QParams>) -> Int8Layer {
        let fold = OutputFold { post_scale: &self.post, bias: &self.bias, relu };
        Int8Layer::new(&self.w, self.k, self.n, &fold, self.input, output).unwrap()
    }
}

#[test]
fn fused_linear_matches_its_integer_reference_exactly_and_float_within_the_step() {
    for (m, k, n, seed) in [(1, 1, 1, 1), (7, 3, 5, 2), (33, 67, 17, 3), (130, 128, 64, 4), (5, 384, 129, 5)] {
        let c = case(k, n, seed);
        let x: Vec<f32> = values(m * k, seed + 9).iter().map(|v| v * 1.5 + 0.5).collect();
        for relu in [false, true] {
            let layer = c.layer(relu, None);
            let mut a = vec![0u8; m * k];
            layer.quantize_input(&x, &mut a).unwrap();
            let (mut fast, mut reference) = (vec![0f32; m * n], vec![0f32; m * n]);
            layer.run(LayerInput::F32(&x), m, LayerOutput::F32(&mut fast)).unwrap();
            layer.run_u7_reference(&a, m, LayerOutput::F32(&mut reference)).unwrap();
            assert_eq!(
                fast.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                reference.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                "m {m} k {k} n {n}"
            );
            // Against the float layer: |x W - x^ W^| <= step_x/2 * sum|w| + sum|x^| * step_w/2 per output.
            let (_, w_scale) = tricons::quant::params::quantize_weights_per_channel(&c.w, k, n);
            for i in 0..m {
                for j in 0..n {
                    let mut exact = 0f64;
                    let (mut sum_w, mut sum_x) = (0f64, 0f64);
                    for kk in 0..k {
                        let xq = c.input.dequantize(a[i * k + kk]) as f64;
                        exact += x[i * k + kk] as f64 * c.w[kk * n + j] as f64;
                        sum_w += c.w[kk * n + j].abs() as f64;
                        sum_x += xq.abs();
                    }
                    let mut want = exact * c.post[j] as f64 + c.bias[j] as f64;
                    if relu {
                        want = want.max(0.0);
                    }
                    let bound = (c.input.scale as f64 / 2.0 * sum_w + sum_x * w_scale[j] as f64 / 2.0)
                        * c.post[j] as f64
                        + 1e-4;
                    let got = fast[i * n + j] as f64;
                    assert!((got - want).abs() <= bound, "({i},{j}): {got} vs {want}, bound {bound}");
                }
            }
        }
    }
}

#[test]
fn u7_output_is_the_float_output_requantised() {
    let c = case(40, 24, 11);
    let out_q = QParams::from_range(0.0, 3.0);
    let (chained, floats) = (c.layer(true, Some(out_q)), c.layer(true, None));
    let x = values(9 * 40, 12);
    let (mut q, mut f) = (vec![0u8; 9 * 24], vec![0f32; 9 * 24]);
    chained.run(LayerInput::F32(&x), 9, LayerOutput::U7(&mut q)).unwrap();
    floats.run(LayerInput::F32(&x), 9, LayerOutput::F32(&mut f)).unwrap();
    let want: Vec<u8> = f.iter().map(|&v| out_q.quantize(v)).collect();
    assert_eq!(q, want);
}

/// Direct convolution in integer arithmetic: the definition `QConv` must reproduce.
fn conv_reference(w_q: &[i8], x_q: &[u8], g: &ConvGeometry, n: usize, zp: i32) -> Vec<i32> {
    let (ho, wo) = g.output_hw().unwrap();
    let [kh, kw] = g.kernel;
    let k = g.patch_len();
    let mut out = vec![0i32; n * ho * wo];
    for co in 0..n {
        for oy in 0..ho {
            for ox in 0..wo {
                let mut acc = 0i32;
                for ci in 0..g.c_in {
                    for ky in 0..kh {
                        for kx in 0..kw {
                            let iy = (oy * g.strides[0] + ky * g.dilations[0]) as isize - g.pads[0] as isize;
                            let ix = (ox * g.strides[1] + kx * g.dilations[1]) as isize - g.pads[1] as isize;
                            let inside = iy >= 0 && ix >= 0 && (iy as usize) < g.h && (ix as usize) < g.w;
                            let v = if inside { x_q[(ci * g.h + iy as usize) * g.w + ix as usize] as i32 } else { zp };
                            acc += (v - zp) * w_q[((ci * kh + ky) * kw + kx) * n + co] as i32;
                        }
                    }
                }
                out[(co * ho + oy) * wo + ox] = acc;
            }
        }
    }
    let _ = k;
    out
}

#[test]
fn qconv_matches_a_direct_integer_convolution_exactly() {
    let geoms = [
        ConvGeometry { c_in: 3, h: 9, w: 7, kernel: [3, 3], strides: [1, 1], pads: [1, 1, 1, 1], dilations: [1, 1] },
        ConvGeometry { c_in: 5, h: 11, w: 8, kernel: [3, 3], strides: [2, 2], pads: [1, 0, 1, 2], dilations: [1, 1] },
        ConvGeometry { c_in: 16, h: 6, w: 6, kernel: [1, 1], strides: [1, 1], pads: [0; 4], dilations: [1, 1] },
        ConvGeometry { c_in: 2, h: 10, w: 10, kernel: [3, 2], strides: [1, 2], pads: [2, 1, 0, 1], dilations: [2, 1] },
    ];
    for (gi, g) in geoms.iter().enumerate() {
        let n = 6;
        let k = g.patch_len();
        let c = case(k, n, 30 + gi as u64);
        let (w_q, w_scale) = tricons::quant::params::quantize_weights_per_channel(&c.w, k, n);
        let x = values(g.c_in * g.h * g.w, 40 + gi as u64);
        let layer = Int8Layer::new(
            &c.w,
            k,
            n,
            &OutputFold { post_scale: &vec![1.0; n], bias: &vec![0.0; n], relu: false },
            c.input,
            None,
        )
        .unwrap();
        let mut x_q = vec![0u8; x.len()];
        layer.quantize_input(&x, &mut x_q).unwrap();
        let (ho, wo) = g.output_hw().unwrap();
        let mut out = vec![0f32; n * ho * wo];
        qconv_reference(&layer, LayerInput::F32(&x), g, &mut out).unwrap();
        let acc = conv_reference(&w_q, &x_q, g, n, c.input.zero_point);
        for (idx, (&got, &a)) in out.iter().zip(&acc).enumerate() {
            let co = idx / (ho * wo);
            let want = (a as f32) * (c.input.scale * w_scale[co]);
            assert_eq!(got.to_bits(), want.to_bits(), "geometry {gi} output {idx}: {got} vs {want}");
        }
    }
}

#[test]
fn a_graph_with_nothing_to_quantize_is_a_clear_error() {
    use tract_onnx::pb::{GraphProto, NodeProto};
    let graph = GraphProto {
        node: vec![NodeProto {
            name: "relu".into(),
            op_type: "Relu".into(),
            input: vec!["x".into()],
            output: vec!["y".into()],
            ..Default::default()
        }],
        ..Default::default()
    };
    let target = ProfileTarget { kind: ModelKind::Pose, model: "m.card.json".into(), onnx_sha256: "00".into() };
    let info = CalibrationInfo { data: "d".into(), frames: 1, runs: 1 };
    let mut stats = std::collections::HashMap::new();
    let mut st = TensorStats::default();
    st.observe(&[0.0, 1.0], 2);
    stats.insert("x".to_string(), st);
    let err = build_profile(target, &graph, &stats, &QuantizeOptions::default(), info).unwrap_err().to_string();
    assert!(err.contains("no node of the model can run in int8"), "{err}");
    assert!(err.contains("no MatMul, Gemm or Conv"), "{err}");
}

#[test]
fn the_shipped_profiles_load_and_name_their_graphs() {
    let pose = QuantProfile::read(Path::new(&repo("models/tricons-pose.int8.json"))).unwrap();
    assert_eq!(pose.kind, ModelKind::Pose);
    let est = PoseEstimator::load(Path::new(&repo("models/tricons-pose.int8.json"))).unwrap();
    assert_eq!(est.quantized().unwrap().quantized, pose.nodes.len());
    let seg = QuantProfile::read(Path::new(&repo("models/maskrcnn-light.int8.json"))).unwrap();
    assert_eq!(seg.kind, ModelKind::Segmenter);
    assert!(!seg.nodes.is_empty() && seg.float.iter().all(|f| !f.reason.is_empty()));
}

#[test]
fn int8_pose_follows_float_on_a_demo_frame() {
    let float = PoseEstimator::load(Path::new(&repo("models/tricons-pose.card.json"))).unwrap();
    let int8 = PoseEstimator::load(Path::new(&repo("models/tricons-pose.int8.json"))).unwrap();
    let rec = open_recording(Path::new(&repo("tests/data/synthnocs-demo"))).unwrap();
    let frame = rec.read_frame(0).unwrap();
    let masks = rec.read_annotations(0).unwrap().unwrap().instance_masks().unwrap();
    let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
    let (a, b) = (float.estimate(&frame, &refs, 0).unwrap(), int8.estimate(&frame, &refs, 0).unwrap());
    assert_eq!(a.len(), b.len());
    let mut compared = 0;
    for (a, b) in a.iter().zip(&b) {
        let (Ok(a), Ok(b)) = (a, b) else { continue };
        compared += 1;
        let dt = (a.camera_from_object.translation_m - b.camera_from_object.translation_m).norm();
        assert!(dt < 0.01, "translation differs by {dt} m");
        for (x, y) in a.size_m.iter().zip(&b.size_m) {
            assert!((x - y).abs() < 0.01, "size {x} vs {y}");
        }
        // int8 is an approximation, not a copy: something must differ.
        assert_ne!(a.keypoints_camera_m, b.keypoints_camera_m);
    }
    assert!(compared > 0);
}

#[test]
fn a_profile_for_another_graph_is_refused_naming_the_profile() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = QuantProfile::read(Path::new(&repo("models/tricons-pose.int8.json"))).unwrap();
    p.model = std::path::PathBuf::from(repo("models/tricons-pose.card.json"));
    let bad_sha = dir.path().join("sha.int8.json");
    let mut q = p.clone();
    q.onnx_sha256 = "0".repeat(64);
    q.write(&bad_sha).unwrap();
    let err = PoseEstimator::load(&bad_sha).unwrap_err().to_string();
    assert!(err.contains("sha.int8.json") && err.contains("onnx_sha256"), "{err}");
    let bad_node = dir.path().join("node.int8.json");
    let mut q = p.clone();
    q.nodes[0].node = "/no/such/MatMul".into();
    q.write(&bad_node).unwrap();
    let err = PoseEstimator::load(&bad_node).unwrap_err().to_string();
    assert!(err.contains("node.int8.json") && err.contains("/no/such/MatMul"), "{err}");
    let kind = dir.path().join("kind.int8.json");
    fs::write(&kind, fs::read_to_string(repo("models/maskrcnn-light.int8.json")).unwrap()).unwrap();
    let err = PoseEstimator::load(&kind).unwrap_err().to_string();
    assert!(err.contains("not for a pose model"), "{err}");
}

#[test]
fn quantize_is_deterministic_and_validate_reports_and_gates() {
    let dir = tempfile::tempdir().unwrap();
    let calib = repo("calibration/synthnocs-calib");
    let model = repo("models/tricons-pose.card.json");
    let (p1, p2) = (dir.path().join("a.int8.json"), dir.path().join("b.int8.json"));
    for p in [&p1, &p2] {
        let o = tricons(&[
            "quantize",
            "--model",
            &model,
            "--calibration",
            &calib,
            "--frames",
            "2",
            "--out",
            p.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let (a, b) = (fs::read_to_string(&p1).unwrap(), fs::read_to_string(&p2).unwrap());
    assert_eq!(a, b, "two calibrations of the same data differ");
    let profile = QuantProfile::read(&p1).unwrap();
    assert_eq!(profile.calibration.frames, 2);
    assert!(profile.nodes.iter().any(|n| n.output_u7.is_some()), "no u7 hand-over between int8 layers");

    let rec = demo_subset(dir.path(), 1, true);
    let json = dir.path().join("v.json");
    let validate = |max_drop: &str| {
        tricons(&[
            "validate",
            "--float",
            &model,
            "--int8",
            p1.to_str().unwrap(),
            "--data",
            rec.to_str().unwrap(),
            "--json",
            json.to_str().unwrap(),
            &format!("--max-drop={max_drop}"),
        ])
    };
    let o = validate("100");
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("5deg2cm") && text.contains("latency"), "{text}");
    let report: serde_json::Value = serde_json::from_str(&fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["passed"], true);
    assert!(report["outputs"][0]["cosine"].as_f64().unwrap() > 0.9);
    // A gate no model can pass (int8 may never be below float by -1 points) fails with exit 1.
    let o = validate("-1");
    assert_clean_failure(&o, "--max-drop");
}

#[test]
fn quantize_refuses_unusable_calibration_and_models_without_int8_nodes() {
    let dir = tempfile::tempdir().unwrap();
    let model = repo("models/tricons-pose.card.json");
    let out = dir.path().join("q.json");
    let out_s = out.to_str().unwrap();
    // Frames without ground-truth masks (and no --segmenter): nothing to calibrate on.
    let rec = demo_subset(dir.path(), 1, false);
    let o = tricons(&["quantize", "--model", &model, "--calibration", rec.to_str().unwrap(), "--out", out_s]);
    assert_clean_failure(&o, "none of its 1 frames is usable");
    // Not a recording.
    let o = tricons(&["quantize", "--model", &model, "--calibration", "no/such/dir", "--out", out_s]);
    assert_clean_failure(&o, "no/such/dir");
    // Every node forced float.
    let calib = repo("calibration/synthnocs-calib");
    let o = tricons(&[
        "quantize",
        "--model",
        &model,
        "--calibration",
        &calib,
        "--frames",
        "1",
        "--keep-float",
        "/",
        "--out",
        out_s,
    ]);
    assert_clean_failure(&o, "no node of the model can run in int8");
    assert!(!out.exists(), "a failed quantize must not leave a profile");
}

#[test]
fn the_most_sensitive_nodes_go_float_and_the_rest_still_loads() {
    use tricons::quant::calibrate::keep_most_sensitive_float;
    let est = PoseEstimator::load(Path::new(&repo("models/tricons-pose.card.json"))).unwrap();
    let proto = est.float_proto().unwrap();
    let graph = proto.graph.as_ref().unwrap();
    let mut p = QuantProfile::read(Path::new(&repo("models/tricons-pose.int8.json"))).unwrap();
    let n = p.nodes.len();
    // Pretend the nodes handing u7 to the next are the most sensitive: the links must be redone.
    let errors: Vec<f64> =
        p.nodes.iter().enumerate().map(|(i, q)| if q.output_u7.is_some() { 1.0 + i as f64 } else { 0.0 }).collect();
    let worst: Vec<String> = {
        let mut idx: Vec<usize> = (0..n).collect();
        idx.sort_by(|&a, &b| errors[b].total_cmp(&errors[a]));
        idx.iter().take(3).map(|&i| p.nodes[i].node.clone()).collect()
    };
    keep_most_sensitive_float(&mut p, graph, &errors, 3, true);
    assert_eq!(p.nodes.len(), n - 3);
    for w in &worst {
        let f = p.float.iter().find(|f| &f.node == w).expect("moved to float");
        assert!(f.reason.starts_with("sensitivity"), "{}", f.reason);
    }
    // Every u7 consumer still has an int8 producer handing it u7: the rewrite accepts it and runs.
    let dir = tempfile::tempdir().unwrap();
    p.model = std::path::PathBuf::from(repo("models/tricons-pose.card.json"));
    let path = dir.path().join("s.int8.json");
    p.write(&path).unwrap();
    let q = PoseEstimator::load(&path).unwrap();
    let rec = open_recording(Path::new(&repo("tests/data/synthnocs-demo"))).unwrap();
    let frame = rec.read_frame(0).unwrap();
    let masks = rec.read_annotations(0).unwrap().unwrap().instance_masks().unwrap();
    let refs: Vec<&[bool]> = masks.iter().map(Vec::as_slice).collect();
    assert!(q.estimate(&frame, &refs, 0).unwrap().iter().any(|o| o.is_ok()));
}

/// The patch-at-a-time unfolding against the column-at-a-time reference: the same bytes on
/// random geometries (kernels 1x1 to 5x3, strides, dilations, asymmetric padding, kernels
/// wider than the padded image's interior).
#[test]
fn im2col_equals_its_reference_on_random_geometries() {
    use tricons::ops::qconv::{im2col_u7, im2col_u7_reference};
    let mut rng = tricons::rng::Rng::new(16);
    let mut below = |n: u64| (rng.next_u64() % n) as usize;
    let mut checked = 0;
    for _ in 0..300 {
        let g = ConvGeometry {
            c_in: 1 + below(4),
            h: 1 + below(9),
            w: 1 + below(9),
            kernel: [1 + below(5), 1 + below(3)],
            strides: [1 + below(3), 1 + below(3)],
            pads: [below(3), below(3), below(3), below(3)],
            dilations: [1 + below(2), 1 + below(2)],
        };
        let Ok((ho, wo)) = g.output_hw() else { continue };
        let x: Vec<u8> = (0..g.c_in * g.h * g.w).map(|_| below(128) as u8).collect();
        let mut want = vec![0u8; ho * wo * g.patch_len()];
        im2col_u7_reference(&x, &g, 200, &mut want).unwrap();
        let mut got = vec![1u8; want.len()];
        im2col_u7(&x, &g, 200, &mut got).unwrap();
        assert_eq!(got, want, "{g:?}");
        checked += 1;
    }
    assert!(checked > 150, "{checked} geometries fit");
}

/// Both patch orders of the kernel against the reference: the same output bits on random
/// geometries (1x1 without unfolding, blocks of positions beyond one, strides, dilations,
/// padding), float and u7 inputs, ReLU and bias; its unfolding equals the reference's
/// columns reordered to `(ky, kx, ci)`.
#[test]
fn channels_last_qconv_gives_the_reference_bits() {
    use tricons::ops::qconv::{im2col_hwc_u7, im2col_u7_reference};
    let mut rng = tricons::rng::Rng::new(17);
    let mut below = |n: u64| (rng.next_u64() % n) as usize;
    let mut checked = 0;
    for trial in 0..120u64 {
        let pointwise = trial % 4 == 0;
        let g = ConvGeometry {
            c_in: 1 + below(12),
            h: 1 + below(24),
            w: 1 + below(24),
            kernel: if pointwise { [1, 1] } else { [1 + below(4), 1 + below(3)] },
            strides: if pointwise { [1, 1] } else { [1 + below(2), 1 + below(2)] },
            pads: if pointwise { [0; 4] } else { [below(2), below(2), below(2), below(2)] },
            dilations: [1 + below(2), 1 + below(2)],
        };
        let Ok((ho, wo)) = g.output_hw() else { continue };
        let (k, n) = (g.patch_len(), 1 + below(20));
        let c = case(k, n, 100 + trial);
        let layer = Int8Layer::new(
            &c.w,
            k,
            n,
            &OutputFold { post_scale: &c.post, bias: &c.bias, relu: trial % 3 == 0 },
            c.input,
            None,
        )
        .unwrap();
        let x = values(g.c_in * g.h * g.w, 200 + trial);
        let mut x_q = vec![0u8; x.len()];
        layer.quantize_input(&x, &mut x_q).unwrap();
        for order in [PatchOrder::Planar, PatchOrder::ChannelsLast] {
            let conv = ConvLayer::with_order(&layer, g.kernel, order).unwrap();
            for input in [LayerInput::F32(&x), LayerInput::U7(&x_q)] {
                let mut want = vec![0f32; n * ho * wo];
                qconv_reference(&layer, input, &g, &mut want).unwrap();
                let mut got = vec![f32::NAN; want.len()];
                qconv(&conv, input, &g, &mut got).unwrap();
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got), bits(&want), "{g:?}, n {n}, {order:?}, input {input:?}");
            }
        }
        let by_channels = ConvLayer::new(&layer, g.kernel).unwrap().order();
        assert_eq!(by_channels == PatchOrder::ChannelsLast, g.c_in >= tricons::ops::qconv::CHANNELS_LAST_MIN_C_IN);
        // the unfolding: reference column (ci, ky, kx) is column (ky, kx, ci) here
        let (hw, taps) = (g.h * g.w, g.kernel[0] * g.kernel[1]);
        let hwc: Vec<u8> = (0..hw * g.c_in).map(|i| x_q[(i % g.c_in) * hw + i / g.c_in]).collect();
        let mut want = vec![0u8; ho * wo * k];
        im2col_u7_reference(&x_q, &g, 99, &mut want).unwrap();
        let p0 = below((ho * wo) as u64);
        let rows = 1 + below((ho * wo - p0) as u64);
        let mut got = vec![0u8; rows * k];
        im2col_hwc_u7(&hwc, &g, 99, p0, rows, &mut got).unwrap();
        for (r, patch) in got.chunks_exact(k).enumerate() {
            for (col, &v) in patch.iter().enumerate() {
                let (tap, ci) = (col / g.c_in, col % g.c_in);
                assert_eq!(v, want[(p0 + r) * k + ci * taps + tap], "{g:?} position {} column {col}", p0 + r);
            }
        }
        checked += 1;
    }
    assert!(checked > 80, "{checked} geometries fit");
    // a 3x3 convolution of more positions than one block (256), as the Mask R-CNN's FPN runs
    let g = ConvGeometry { c_in: 8, h: 20, w: 30, kernel: [3, 3], strides: [1, 1], pads: [1; 4], dilations: [1, 1] };
    let (k, n) = (g.patch_len(), 16);
    let c = case(k, n, 7);
    let layer =
        Int8Layer::new(&c.w, k, n, &OutputFold { post_scale: &c.post, bias: &c.bias, relu: true }, c.input, None)
            .unwrap();
    let x = values(g.c_in * g.h * g.w, 8);
    let (mut want, mut got) = (vec![0f32; n * 600], vec![0f32; n * 600]);
    qconv_reference(&layer, LayerInput::F32(&x), &g, &mut want).unwrap();
    qconv(&ConvLayer::new(&layer, g.kernel).unwrap(), LayerInput::F32(&x), &g, &mut got).unwrap();
    assert!(got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits()));
    // what is not a permutation, and a kernel the weights do not fit, are errors
    assert!(layer.with_rows_permuted(&vec![0; k]).is_err());
    assert!(ConvLayer::new(&layer, [5, 5]).is_err());
}
