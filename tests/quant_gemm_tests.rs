//! int8 GEMM kernels (`tricons::quant::gemm`): every kernel of this CPU against the scalar
//! reference, bit for bit, over awkward shapes; the reference against hand-computed numbers;
//! quantisation edge cases; argument errors.

use tricons::quant::gemm::{
    GemmError, Kernel, Output, OutputStage, PackedWeights, qgemm, qgemm_reference, quantize_u7, quantize_u7_reference,
};

/// xorshift64*: deterministic test data without dependencies.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in lo..=hi.
    fn int(&mut self, lo: i32, hi: i32) -> i32 {
        lo + (self.next() % (hi - lo + 1) as u64) as i32
    }
    fn f32(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next() >> 40) as f32 / (1u64 << 24) as f32)
    }
    /// u7 with the extremes 0 and 127 overrepresented.
    fn u7(&mut self) -> u8 {
        match self.int(0, 9) {
            0 => 0,
            1 => 127,
            _ => self.int(0, 127) as u8,
        }
    }
    /// Weight in -127..=127 with the extremes overrepresented.
    fn w(&mut self) -> i8 {
        match self.int(0, 9) {
            0 => -127,
            1 => 127,
            2 => 0,
            _ => self.int(-127, 127) as i8,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    F32,
    F32T,
    U7,
}

/// Stage and output options of one case.
#[derive(Clone, Copy, Debug)]
struct Opts {
    kind: Kind,
    bias: bool,
    relu: bool,
    /// Extra row stride of `a` and of the output.
    pad: usize,
}

struct Case {
    m: usize,
    k: usize,
    n: usize,
    lda: usize,
    a: Vec<u8>,
    w: Vec<i8>,
    za: i32,
    scale: Vec<f32>,
    bias: Vec<f32>,
}

impl Case {
    fn new(rng: &mut Rng, m: usize, k: usize, n: usize, pad: usize) -> Self {
        let lda = k + pad;
        // The row padding holds 255s: a kernel that reads it into the sums fails.
        let a = (0..m * lda).map(|i| if i % lda < k { rng.u7() } else { 255 }).collect();
        let w = (0..k * n).map(|_| rng.w()).collect();
        // Scales so that v spreads over about ±64 (requantisation covers 0..=127 and clamps).
        let s = 1.0 / (k as f32).sqrt() / 40.0;
        let scale = (0..n).map(|j| if j % 5 == 4 { -s } else { s * rng.f32(0.5, 1.5) }).collect();
        let bias = (0..n).map(|_| rng.f32(-20.0, 20.0)).collect();
        Self { m, k, n, lda, a, w, za: rng.int(0, 127), scale, bias }
    }

    /// Runs `gemm` into a fresh output (filled with a sentinel), returned as bits.
    fn run(
        &self,
        w: &PackedWeights,
        o: Opts,
        gemm: impl Fn(&[u8], usize, usize, &PackedWeights, &OutputStage<'_>, Output<'_>) -> Result<(), GemmError>,
    ) -> Vec<u32> {
        let stage = OutputStage {
            a_zero_point: self.za,
            scale: &self.scale,
            bias: o.bias.then_some(&self.bias[..]),
            relu: o.relu,
        };
        let (m, n) = (self.m, self.n);
        match o.kind {
            Kind::F32 | Kind::F32T => {
                let (rows, ld) = match o.kind {
                    Kind::F32 => (m, n + o.pad),
                    _ => (n, m + o.pad),
                };
                let mut out = vec![f32::from_bits(0x7fc0_dead); rows * ld];
                let output = match o.kind {
                    Kind::F32 => Output::F32 { out: &mut out, ld },
                    _ => Output::F32Transposed { out: &mut out, ld },
                };
                gemm(&self.a, m, self.lda, w, &stage, output).expect("gemm");
                out.iter().map(|v| v.to_bits()).collect()
            }
            Kind::U7 => {
                let ld = n + o.pad;
                let mut out = vec![200u8; m * ld];
                let output = Output::U7 { out: &mut out, ld, inv_scale: 1.7, zero_point: 60 };
                gemm(&self.a, m, self.lda, w, &stage, output).expect("gemm");
                out.iter().map(|&v| u32::from(v)).collect()
            }
        }
    }
}

/// Every available kernel gives the reference's bits for this case and these options.
fn check_case(case: &Case, opts: &[Opts]) {
    for kernel in Kernel::available() {
        let w = PackedWeights::with_kernel(&case.w, case.k, case.n, kernel).expect("pack");
        assert_eq!(w.kernel(), kernel);
        for &o in opts {
            let want = case.run(&w, o, qgemm_reference);
            let got = case.run(&w, o, qgemm);
            if let Some(i) = (0..want.len()).find(|&i| want[i] != got[i]) {
                panic!(
                    "{kernel} m {} k {} n {} {o:?}: element {i} is {:#x}, reference {:#x}",
                    case.m, case.k, case.n, got[i], want[i]
                );
            }
        }
    }
}

#[test]
fn kernels_match_reference_on_a_grid_of_shapes() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let kinds = [Kind::F32, Kind::F32T, Kind::U7];
    let mut count = 0;
    for &m in &[1usize, 2, 3, 5, 7, 16, 17, 33, 65] {
        for &k in &[1usize, 2, 3, 4, 5, 7, 16, 17, 33, 64, 65, 130] {
            for &n in &[1usize, 3, 7, 16, 17, 33, 64, 65, 130] {
                // Stage options cycle with the case number: every combination gets many shapes.
                let pad = [0, 3][count % 2];
                let opts = Opts { kind: kinds[count % 3], bias: count % 4 < 2, relu: count % 7 < 3, pad };
                check_case(&Case::new(&mut rng, m, k, n, pad), &[opts]);
                count += 1;
            }
        }
    }
}

#[test]
fn kernels_match_reference_for_every_stage_option() {
    let mut rng = Rng(42);
    for &(m, k, n) in &[(13, 37, 70), (6, 129, 64), (31, 20, 9), (1, 1, 1)] {
        let mut opts = Vec::new();
        for kind in [Kind::F32, Kind::F32T, Kind::U7] {
            for bias in [false, true] {
                for relu in [false, true] {
                    for pad in [0, 5] {
                        opts.push(Opts { kind, bias, relu, pad });
                    }
                }
            }
        }
        check_case(&Case::new(&mut rng, m, k, n, 2), &opts);
    }
}

#[test]
fn kernels_match_reference_on_network_shapes() {
    let mut rng = Rng(7);
    // Per-point features; a conv3x3 with 16 input channels; the first conv (3 channels);
    // a wide layer (panels of every width).
    for &(m, k, n) in &[(512, 128, 128), (100, 144, 32), (77, 27, 16), (9, 96, 672)] {
        let case = Case::new(&mut rng, m, k, n, 0);
        let opts = [
            Opts { kind: Kind::F32, bias: true, relu: true, pad: 0 },
            Opts { kind: Kind::F32T, bias: true, relu: false, pad: 0 },
            Opts { kind: Kind::U7, bias: false, relu: true, pad: 0 },
        ];
        check_case(&case, &opts);
    }
}

/// Extreme accumulators (all 127 x ±127 over a long k, zero points 0 and 127) are exact.
#[test]
fn extreme_values_accumulate_exactly() {
    let (m, k, n) = (7, 1153, 35);
    for (av, wv, za) in [(127u8, 127i8, 0), (127, -127, 127), (0, -127, 127), (127, -128, 3)] {
        let case = Case {
            m,
            k,
            n,
            lda: k,
            a: vec![av; m * k],
            w: vec![wv; k * n],
            za,
            scale: vec![1.0; n],
            bias: vec![0.5; n],
        };
        let o = Opts { kind: Kind::F32, bias: false, relu: false, pad: 0 };
        let expect = ((i32::from(av) - za) * i32::from(wv) * k as i32) as f32;
        for kernel in Kernel::available() {
            let w = PackedWeights::with_kernel(&case.w, k, n, kernel).expect("pack");
            assert_eq!(w.col_sums(), vec![i32::from(wv) * k as i32; n]);
            let got = case.run(&w, o, qgemm);
            assert!(got.iter().all(|&b| f32::from_bits(b) == expect), "{kernel} a {av} w {wv}: want {expect}");
        }
        check_case(&case, &[o, Opts { kind: Kind::U7, bias: true, relu: true, pad: 0 }]);
    }
}

/// The reference against numbers worked out by hand.
#[test]
fn reference_matches_hand_computed_numbers() {
    // a = [[1 2 3] [4 5 6]], w = [[1 -1] [2 0] [-3 4]]: acc = [[-4 11] [-4 20]], col sums [0 3].
    let a = [1u8, 2, 3, 4, 5, 6];
    let w = PackedWeights::new(&[1, -1, 2, 0, -3, 4], 3, 2).expect("pack");
    assert_eq!((w.k(), w.n(), w.col_sums()), (3, 2, &[0, 3][..]));
    assert_eq!(w.weight(2, 0), Some(-3));
    assert_eq!(w.weight(3, 0), None);
    let (scale, bias) = ([0.5f32, 0.25], [1.0f32, -1.0]);
    // za 1: corrected [[-4 8] [-4 17]]; * scale [[-2 2] [-2 4.25]]; + bias [[-1 1] [-1 3.25]].
    let stage = OutputStage { a_zero_point: 1, scale: &scale, bias: Some(&bias), relu: false };
    for gemm in [qgemm_reference, qgemm] {
        let mut out = [0f32; 4];
        gemm(&a, 2, 3, &w, &stage, Output::F32 { out: &mut out, ld: 2 }).expect("gemm");
        assert_eq!(out, [-1.0, 1.0, -1.0, 3.25]);

        let relu = OutputStage { relu: true, ..stage };
        let mut out = [9f32; 5];
        gemm(&a, 2, 3, &w, &relu, Output::F32Transposed { out: &mut out, ld: 2 }).expect("gemm");
        assert_eq!(out, [0.0, 0.0, 1.0, 3.25, 9.0]);
        assert_eq!(out[0].to_bits(), 0, "relu gives +0.0");

        // * 2 + 10: [0 2] [0 6.5] -> 6.5 is a tie, rounded to even 6.
        let mut out = [0u8; 4];
        gemm(&a, 2, 3, &w, &relu, Output::U7 { out: &mut out, ld: 2, inv_scale: 2.0, zero_point: 10 }).expect("gemm");
        assert_eq!(out, [10, 12, 10, 16]);

        // No bias, no relu, za 0: the raw products scaled by 1.
        let raw = OutputStage { a_zero_point: 0, scale: &[1.0, 1.0], bias: None, relu: false };
        let mut out = [0f32; 4];
        gemm(&a, 2, 3, &w, &raw, Output::F32 { out: &mut out, ld: 2 }).expect("gemm");
        assert_eq!(out, [-4.0, 11.0, -4.0, 20.0]);
    }
}

#[test]
fn quantize_matches_reference_on_edge_cases() {
    let mut x = vec![
        f32::NAN,
        -f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        0.0,
        -0.0,
        0.5,
        1.5,
        2.5,
        -0.5,
        -1.5,
        -2.5,
        63.5,
        -60.5,
        1e30,
        -1e30,
        3e9,
        -3e9,
        f32::MAX,
        f32::MIN,
        f32::MIN_POSITIVE,
        1e-45,
        127.0,
        127.5,
        128.0,
        -1.0,
    ];
    let mut rng = Rng(3);
    x.extend((0..1000).map(|_| rng.f32(-200.0, 200.0)));
    x.extend((0..100).map(|_| rng.int(-300, 300) as f32 + 0.5));
    for inv_scale in [1.0, 0.5, 2.0, 1.0 / 3.0, 1e-3, 1e9] {
        for zp in [0, 1, 64, 127] {
            for len in [x.len(), 1, 7, 15, 16, 17, 33] {
                let (mut want, mut got) = (vec![0u8; len], vec![0u8; len]);
                quantize_u7_reference(&x[..len], inv_scale, zp, &mut want).expect("quantize");
                quantize_u7(&x[..len], inv_scale, zp, &mut got).expect("quantize");
                assert_eq!(got, want, "inv_scale {inv_scale} zp {zp} len {len}");
            }
        }
    }
    // Hand-checked values at inv_scale 1, zero point 10.
    let mut q = [0u8; 10];
    quantize_u7(&x[..10], 1.0, 10, &mut q).expect("quantize");
    assert_eq!(q, [10, 10, 127, 0, 10, 10, 10, 12, 12, 10]);
    let mut q = [0u8; 2];
    quantize_u7(&[-11.5, -12.5], 1.0, 10, &mut q).expect("quantize");
    assert_eq!(q, [0, 0]);
    quantize_u7(&[-10.5, 117.5], 1.0, 10, &mut q).expect("quantize");
    assert_eq!(q, [0, 127]);
    quantize_u7(&[-9.5, 115.5], 1.0, 10, &mut q).expect("quantize");
    assert_eq!(q, [0, 126]);
}

#[test]
fn bad_arguments_are_errors() {
    let w = PackedWeights::new(&[1; 12], 3, 4).expect("pack");
    let (scale, bias) = ([1.0f32; 4], [0.0f32; 4]);
    let stage = OutputStage { a_zero_point: 0, scale: &scale, bias: Some(&bias), relu: false };
    let a = [1u8; 6];
    let mut out = [0f32; 8];
    let mut out8 = [0u8; 8];
    let len = |e: Result<(), GemmError>| matches!(e, Err(GemmError::Len { .. }));

    for gemm in [qgemm, qgemm_reference] {
        assert_eq!(gemm(&a, 2, 3, &w, &stage, Output::F32 { out: &mut out, ld: 4 }), Ok(()));
        assert!(len(gemm(&a[..5], 2, 3, &w, &stage, Output::F32 { out: &mut out, ld: 4 })));
        assert!(len(gemm(&a, 3, 3, &w, &stage, Output::F32 { out: &mut out, ld: 4 })));
        assert!(len(gemm(&a, 2, 3, &w, &stage, Output::F32 { out: &mut out[..7], ld: 4 })));
        assert!(len(gemm(&a, 2, 3, &w, &stage, Output::F32Transposed { out: &mut out[..7], ld: 2 })));
        assert!(len(gemm(
            &a,
            2,
            3,
            &w,
            &stage,
            Output::U7 { out: &mut out8[..7], ld: 4, inv_scale: 1.0, zero_point: 0 }
        )));
        assert!(len(gemm(&a, 2, 4, &w, &stage, Output::F32 { out: &mut out, ld: 4 })));
        assert!(matches!(
            gemm(&a, 2, 2, &w, &stage, Output::F32 { out: &mut out, ld: 4 }),
            Err(GemmError::Stride { what: "a", ld: 2, min: 3 })
        ));
        assert!(matches!(
            gemm(&a, 2, 3, &w, &stage, Output::F32 { out: &mut out, ld: 3 }),
            Err(GemmError::Stride { .. })
        ));
        assert!(matches!(
            gemm(&a, 2, 3, &w, &stage, Output::F32Transposed { out: &mut out, ld: 1 }),
            Err(GemmError::Stride { .. })
        ));
        let short_scale = OutputStage { scale: &scale[..3], ..stage };
        assert!(len(gemm(&a, 2, 3, &w, &short_scale, Output::F32 { out: &mut out, ld: 4 })));
        let long_bias = OutputStage { bias: Some(&[0.0; 5]), ..stage };
        assert!(len(gemm(&a, 2, 3, &w, &long_bias, Output::F32 { out: &mut out, ld: 4 })));
        assert_eq!(
            gemm(&a, 2, 3, &w, &stage, Output::U7 { out: &mut out8, ld: 4, inv_scale: 1.0, zero_point: 128 }),
            Err(GemmError::ZeroPoint(128))
        );
        assert_eq!(
            gemm(&a, usize::MAX, usize::MAX, &w, &stage, Output::F32 { out: &mut out, ld: 4 }),
            Err(GemmError::Overflow)
        );
        // m = 0 is an empty product.
        assert_eq!(gemm(&[], 0, 3, &w, &stage, Output::F32 { out: &mut [], ld: 4 }), Ok(()));
    }

    assert!(matches!(
        PackedWeights::new(&[1; 11], 3, 4),
        Err(GemmError::Len { what: "weights", expected: 12, got: 11 })
    ));
    assert!(matches!(PackedWeights::new(&[], 0, 4), Err(GemmError::EmptyWeights { .. })));
    assert!(matches!(PackedWeights::new(&[1; 4], usize::MAX, 2), Err(GemmError::Overflow)));
    for kernel in Kernel::ALL {
        let packed = PackedWeights::with_kernel(&[1; 12], 3, 4, kernel);
        assert_eq!(packed.is_ok(), kernel.is_available(), "{kernel}");
        if !kernel.is_available() {
            assert!(matches!(packed, Err(GemmError::Unavailable(k)) if k == kernel));
        }
    }

    let mut q = [0u8; 3];
    assert!(len(quantize_u7(&[1.0; 4], 1.0, 0, &mut q)));
    assert!(len(quantize_u7_reference(&[1.0; 2], 1.0, 0, &mut q)));
    assert_eq!(quantize_u7(&[1.0; 3], 1.0, -1, &mut q), Err(GemmError::ZeroPoint(-1)));
}

#[test]
fn the_best_kernel_is_available_and_used_by_default() {
    let best = Kernel::best();
    println!("kernels of this CPU: {:?}", Kernel::available());
    assert!(best.is_available());
    assert_eq!(Kernel::available().last(), Some(&best));
    assert_eq!(PackedWeights::new(&[1; 4], 2, 2).expect("pack").kernel(), best);
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx512vnni") && is_x86_feature_detected!("avx512bw") {
        assert_eq!(best, Kernel::Avx512Vnni);
    }
    #[cfg(target_arch = "aarch64")]
    assert!(Kernel::available().contains(&Kernel::Neon));
}
