//! int8 GEMM (`tricons::quant::gemm`) against tract's own f32 matmul, single-threaded.
//!
//! `cargo bench --bench qgemm`. Shapes: the pose network's per-point layers ([512 x 128] x
//! [128 x 128], [512 x 384] x [384 x 128], [4096 x 128] x [128 x 128]) and a 3x3 convolution
//! of 128 channels at 80 x 80 as a GEMM ([6400 x 1152] x [1152 x 128]) and an early one (16 to
//! 32 channels at 160 x 160: [25600 x 144] x [144 x 32]). For each:
//! `tract-f32` (a one-node TypedModel, EinSum `mk,kn->mn` with constant weights, optimised:
//! tract's packed f32 kernels), `int8` ([`qgemm`] with the best kernel of the CPU, f32 output
//! with bias and ReLU), `int8+quantize` (the f32 input quantised first, as a layer fed with
//! floats does), `int8-u7out` (output requantised for the next int8 layer) and, for the
//! convolutions, `int8-nchw` (transposed output). Throughput is in multiply-adds (m * k * n).
//! `qgemm-kernels` runs every kernel of the CPU on one shape. `qconv` runs whole int8
//! convolutions (`tricons::ops::qconv`, f32 NCHW in and out, as the Mask R-CNN's `QConv`
//! nodes) at the light Mask R-CNN's geometries: `qconv` in both patch orders against
//! `qconv_reference` (the whole image unfolded in ONNX order), and the product alone.

use std::hint::black_box;

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::ops::einsum::EinSum;
use tricons::ops::qconv::{ConvGeometry, ConvLayer, PatchOrder, qconv, qconv_reference};
use tricons::quant::gemm::{Kernel, Output, OutputStage, PackedWeights, qgemm, quantize_u7};
use tricons::quant::{Int8Layer, LayerInput, LayerOutput, OutputFold, QParams};

/// Deterministic values in [-1, 1).
fn values(len: usize, seed: u64) -> Vec<f32> {
    let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    (0..len)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        })
        .collect()
}

/// tract's f32 `[m, k] x [k, n]` with the weights as a constant, optimised and runnable.
fn tract_matmul(m: usize, k: usize, n: usize, w: &[f32]) -> TractResult<impl Fn(TValue) -> TractResult<TVec<TValue>>> {
    let mut model = TypedModel::default();
    let a = model.add_source("a", f32::fact([m, k]))?;
    let b = model.add_const("w", Tensor::from_shape(&[k, n], w)?)?;
    let out = model.wire_node("matmul", EinSum::new("mk,kn->mn".parse()?, f32::datum_type()), &[a, b])?;
    model.select_output_outlets(&out)?;
    let plan = model.into_optimized()?.into_runnable()?;
    Ok(move |x: TValue| plan.run(tvec![x]))
}

fn bench_qgemm(c: &mut Criterion) {
    let shapes = [
        ("pts512-128x128", 512, 128, 128),
        ("pts512-384x128", 512, 384, 128),
        ("pts4096-128x128", 4096, 128, 128),
        ("conv3x3-80x80-128ch", 6400, 1152, 128),
        ("conv3x3-160x160-16to32ch", 25600, 144, 32),
    ];
    let kernel = Kernel::best();
    let mut group = c.benchmark_group(format!("qgemm-{kernel}"));
    for (label, m, k, n) in shapes {
        group.throughput(Throughput::Elements((m * k * n) as u64));
        let x = values(m * k, 1);
        let w = values(k * n, 2);
        let bias = values(n, 3);

        let run = tract_matmul(m, k, n, &w).expect("tract model");
        let input: TValue = Tensor::from_shape(&[m, k], &x).expect("input").into();
        group.bench_function(BenchmarkId::new("tract-f32", label), |b| {
            b.iter(|| black_box(run(input.clone()).expect("tract run")))
        });

        // Symmetric per-tensor weight scale, u7 input in [-1, 1) with zero point 64.
        let (sw, sa, za) = (1.0 / 127.0, 1.0 / 63.0, 64);
        let wq: Vec<i8> = w.iter().map(|&v| (v / sw).round().clamp(-127.0, 127.0) as i8).collect();
        let packed = PackedWeights::new(&wq, k, n).expect("pack");
        let mut a = vec![0u8; m * k];
        quantize_u7(&x, 1.0 / sa, za, &mut a).expect("quantize");
        let scale = vec![sa * sw; n];
        let stage = OutputStage { a_zero_point: za, scale: &scale, bias: Some(&bias), relu: true };
        let mut out = vec![0f32; m * n];
        group.bench_function(BenchmarkId::new("int8", label), |b| {
            b.iter(|| qgemm(black_box(&a), m, k, &packed, &stage, Output::F32 { out: &mut out, ld: n }).expect("qgemm"))
        });
        group.bench_function(BenchmarkId::new("int8+quantize", label), |b| {
            b.iter(|| {
                quantize_u7(black_box(&x), 1.0 / sa, za, &mut a).expect("quantize");
                qgemm(&a, m, k, &packed, &stage, Output::F32 { out: &mut out, ld: n }).expect("qgemm")
            })
        });
        let mut out8 = vec![0u8; m * n];
        group.bench_function(BenchmarkId::new("int8-u7out", label), |b| {
            b.iter(|| {
                let out = Output::U7 { out: &mut out8, ld: n, inv_scale: 10.0, zero_point: 20 };
                qgemm(black_box(&a), m, k, &packed, &stage, out).expect("qgemm")
            })
        });
        if m > 4096 {
            group.bench_function(BenchmarkId::new("int8-nchw", label), |b| {
                b.iter(|| {
                    qgemm(black_box(&a), m, k, &packed, &stage, Output::F32Transposed { out: &mut out, ld: m })
                        .expect("qgemm")
                })
            });
        }
    }
    group.finish();
}

/// Every kernel of the CPU on one shape ([4096 x 128] x [128 x 128], f32 output).
fn bench_kernels(c: &mut Criterion) {
    let (m, k, n) = (4096, 128, 128);
    let mut group = c.benchmark_group("qgemm-kernels");
    group.throughput(Throughput::Elements((m * k * n) as u64));
    let a: Vec<u8> = values(m * k, 4).iter().map(|v| (v * 63.0 + 64.0) as u8).collect();
    let w: Vec<i8> = values(k * n, 5).iter().map(|v| (v * 127.0) as i8).collect();
    let scale = vec![1e-4f32; n];
    let stage = OutputStage { a_zero_point: 64, scale: &scale, bias: None, relu: false };
    let mut out = vec![0f32; m * n];
    for kernel in Kernel::available() {
        let packed = PackedWeights::with_kernel(&w, k, n, kernel).expect("pack");
        group.bench_function(BenchmarkId::new(kernel.name(), "pts4096-128x128"), |b| {
            b.iter(|| qgemm(black_box(&a), m, k, &packed, &stage, Output::F32 { out: &mut out, ld: n }).expect("qgemm"))
        });
    }
    group.finish();
}

/// Whole int8 convolutions at the light Mask R-CNN's geometries (640x480 frames run at
/// 448x320 after its resize).
fn bench_qconv(c: &mut Criterion) {
    let conv = |c_in, h, w, k, s, p| ConvGeometry {
        c_in,
        h,
        w,
        kernel: [k, k],
        strides: [s, s],
        pads: [p; 4],
        dilations: [1, 1],
    };
    let cases = [
        ("fpn3x3-128ch-40x56", conv(128, 40, 56, 3, 1, 1), 128),
        ("maskhead3x3-128ch-14x14", conv(128, 14, 14, 3, 1, 1), 128),
        ("stem3x3s2-3to16-320x448", conv(3, 320, 448, 3, 2, 1), 16),
        ("pointwise-40to120-40x56", conv(40, 40, 56, 1, 1, 0), 120),
        ("pointwise-960to128-10x14", conv(960, 10, 14, 1, 1, 0), 128),
    ];
    let mut group = c.benchmark_group("qconv");
    for (label, g, n) in cases {
        let (ho, wo) = g.output_hw().expect("geometry");
        let k = g.patch_len();
        group.throughput(Throughput::Elements((ho * wo * k * n) as u64));
        let fold = OutputFold { post_scale: &vec![1.0; n], bias: &values(n, 6), relu: true };
        let layer =
            Int8Layer::new(&values(k * n, 7), k, n, &fold, QParams::from_range(-1.0, 1.0), None).expect("layer");
        let x = values(g.c_in * g.h * g.w, 8);
        let mut out = vec![0f32; n * ho * wo];
        group.bench_function(BenchmarkId::new("reference", label), |b| {
            b.iter(|| qconv_reference(&layer, LayerInput::F32(black_box(&x)), &g, &mut out).expect("qconv"))
        });
        for (name, order) in [("planar", PatchOrder::Planar), ("channels-last", PatchOrder::ChannelsLast)] {
            let conv = ConvLayer::with_order(&layer, g.kernel, order).expect("layer");
            group.bench_function(BenchmarkId::new(name, label), |b| {
                b.iter(|| qconv(&conv, LayerInput::F32(black_box(&x)), &g, &mut out).expect("qconv"))
            });
        }
        let fast = ConvLayer::new(&layer, g.kernel).expect("layer");
        let patches = vec![64u8; ho * wo * k];
        group.bench_function(BenchmarkId::new("product-only", label), |b| {
            b.iter(|| {
                fast.layer().run_u7(black_box(&patches), ho * wo, LayerOutput::F32Transposed(&mut out)).expect("gemm")
            })
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench_qgemm, bench_kernels, bench_qconv
}
criterion_main!(benches);
