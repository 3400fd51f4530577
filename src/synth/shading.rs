//! Materials with procedural textures, and the lighting model (ambient plus
//! directional Lambert lights with a little Blinn-Phong specular, two-sided).

use crate::rng::Rng;

/// A procedural texture pattern, evaluated in an item's texture coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pattern {
    /// Uniform base colour.
    Solid,
    /// Stripes across `axis` (0 x, 1 y, 2 z) with `freq` stripes per unit.
    Stripes {
        /// Axis the stripes vary along.
        axis: u8,
        /// Stripes per texture unit.
        freq: f32,
    },
    /// 3D checker with `freq` cells per unit.
    Checker {
        /// Cells per texture unit.
        freq: f32,
    },
    /// Smooth value noise blending base and alt.
    Noise {
        /// Noise cells per texture unit.
        freq: f32,
    },
    /// Wood-like rings: noisy stripes along x.
    Wood {
        /// Rings per texture unit.
        freq: f32,
    },
    /// A label band between y0 and y1 in the alt colour, with thin stripes of
    /// the base colour inside (bottle and can labels).
    Band {
        /// Lower edge of the band (texture y).
        y0: f32,
        /// Upper edge of the band (texture y).
        y1: f32,
        /// Stripes per texture unit inside the band.
        freq: f32,
    },
}

/// A surface material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Base albedo, linear RGB in [0, 1].
    pub base: [f32; 3],
    /// Second colour of the pattern.
    pub alt: [f32; 3],
    /// Texture pattern.
    pub pattern: Pattern,
    /// Specular strength in [0, 1].
    pub specular: f32,
    /// Blinn-Phong exponent.
    pub shininess: f32,
}

impl Material {
    /// A plain material.
    pub const fn solid(base: [f32; 3], specular: f32) -> Material {
        Material { base, alt: base, pattern: Pattern::Solid, specular, shininess: 24.0 }
    }

    /// Albedo at texture coordinate `p`.
    pub fn albedo(&self, p: [f32; 3]) -> [f32; 3] {
        let t = match self.pattern {
            Pattern::Solid => 0.0,
            Pattern::Stripes { axis, freq } => square(p[usize::from(axis.min(2))] * freq),
            Pattern::Checker { freq } => {
                let s = (p[0] * freq).floor() + (p[1] * freq).floor() + (p[2] * freq).floor();
                if (s as i64).rem_euclid(2) == 0 { 0.0 } else { 1.0 }
            }
            Pattern::Noise { freq } => value_noise([p[0] * freq, p[1] * freq, p[2] * freq]),
            Pattern::Wood { freq } => {
                let n = value_noise([p[0] * 1.5, p[1] * 1.5, p[2] * 12.0]);
                let r = (p[0] * freq + 0.8 * n).fract().abs();
                r * r * 0.8
            }
            Pattern::Band { y0, y1, freq } => {
                if p[1] >= y0 && p[1] <= y1 {
                    if square(p[1] * freq) > 0.5 && ((p[1] - y0) / (y1 - y0) - 0.5).abs() < 0.3 { 0.35 } else { 1.0 }
                } else {
                    0.0
                }
            }
        };
        lerp3(self.base, self.alt, t)
    }

    /// A random material: a random colour, sometimes patterned.
    pub fn random(rng: &mut Rng, pattern_chance: f64) -> Material {
        let base = random_color(rng);
        let alt = random_color(rng);
        let pattern = if rng.chance(pattern_chance) {
            match rng.below(4) {
                0 => Pattern::Stripes { axis: rng.below(3) as u8, freq: rng.range(3.0, 14.0) as f32 },
                1 => Pattern::Checker { freq: rng.range(3.0, 10.0) as f32 },
                2 => Pattern::Noise { freq: rng.range(2.0, 12.0) as f32 },
                _ => Pattern::Wood { freq: rng.range(4.0, 12.0) as f32 },
            }
        } else {
            Pattern::Solid
        };
        Material { base, alt, pattern, specular: rng.range(0.0, 0.35) as f32, shininess: rng.range(8.0, 64.0) as f32 }
    }
}

/// A random albedo: saturated colours, greys and dark tones.
pub fn random_color(rng: &mut Rng) -> [f32; 3] {
    let kind = rng.below(5);
    if kind == 0 {
        let g = rng.range(0.05, 0.9) as f32;
        [g, g, g]
    } else {
        let h = rng.uniform() as f32;
        let s = rng.range(0.25, 0.95) as f32;
        let v = rng.range(0.2, 0.95) as f32;
        hsv(h, s, v)
    }
}

/// HSV (all in [0, 1]) to RGB.
pub fn hsv(h: f32, s: f32, v: f32) -> [f32; 3] {
    let h6 = (h.fract() * 6.0).min(5.9999);
    let i = h6.floor();
    let f = h6 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    match i as u8 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

fn square(x: f32) -> f32 {
    if x - x.floor() < 0.5 { 0.0 } else { 1.0 }
}

fn lerp3(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
}

fn lattice(x: i32, y: i32, z: i32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8DA6_B343)
        ^ (y as u32).wrapping_mul(0xD816_3841)
        ^ (z as u32).wrapping_mul(0xCB1A_B31F);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5BD1_E995);
    h ^= h >> 15;
    (h & 0xFFFF) as f32 / 65535.0
}

/// Trilinear value noise in [0, 1].
pub fn value_noise(p: [f32; 3]) -> f32 {
    let f = [p[0].floor(), p[1].floor(), p[2].floor()];
    let (x, y, z) = (f[0] as i32, f[1] as i32, f[2] as i32);
    let s = |t: f32| t * t * (3.0 - 2.0 * t);
    let (u, v, w) = (s(p[0] - f[0]), s(p[1] - f[1]), s(p[2] - f[2]));
    let l = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let x00 = l(lattice(x, y, z), lattice(x + 1, y, z), u);
    let x10 = l(lattice(x, y + 1, z), lattice(x + 1, y + 1, z), u);
    let x01 = l(lattice(x, y, z + 1), lattice(x + 1, y, z + 1), u);
    let x11 = l(lattice(x, y + 1, z + 1), lattice(x + 1, y + 1, z + 1), u);
    l(l(x00, x10, v), l(x01, x11, v), w)
}

/// A directional light: unit direction towards the light (camera frame) and intensity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Unit vector from the surface towards the light, camera frame.
    pub dir: [f32; 3],
    /// Intensity (RGB).
    pub color: [f32; 3],
}

/// Scene lighting.
#[derive(Clone, Debug, PartialEq)]
pub struct Lighting {
    /// Ambient intensity (RGB).
    pub ambient: [f32; 3],
    /// Directional lights (1 or 2).
    pub lights: Vec<Light>,
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Result of shading one pixel.
pub struct Shaded {
    /// Colour in [0, 1] (not clamped).
    pub rgb: [f32; 3],
    /// Albedo luminance (for the sensor's dark-surface dropout).
    pub albedo_luma: f32,
    /// Largest specular term (for the sensor's specular dropout).
    pub specular: f32,
}

impl Lighting {
    /// Shades a surface point with unit normal `n` seen along the unit view
    /// ray `d` (camera to point). Two-sided: the normal is flipped to face the camera.
    pub fn shade(&self, mat: &Material, albedo: [f32; 3], n: [f32; 3], d: [f32; 3]) -> Shaded {
        let n = if dot(n, d) > 0.0 { [-n[0], -n[1], -n[2]] } else { n };
        let v = [-d[0], -d[1], -d[2]];
        let mut diffuse = self.ambient;
        let mut spec = 0.0f32;
        let mut spec_rgb = [0.0f32; 3];
        for l in &self.lights {
            let ndl = dot(n, l.dir);
            if ndl <= 0.0 {
                continue;
            }
            for (d, c) in diffuse.iter_mut().zip(l.color) {
                *d += c * ndl;
            }
            if mat.specular > 0.0 {
                let h = [l.dir[0] + v[0], l.dir[1] + v[1], l.dir[2] + v[2]];
                let hn = dot(h, h).sqrt().max(1e-6);
                let ndh = (dot(n, h) / hn).max(0.0);
                let s = mat.specular * ndh.powf(mat.shininess);
                spec = spec.max(s);
                for (o, c) in spec_rgb.iter_mut().zip(l.color) {
                    *o += s * c;
                }
            }
        }
        let rgb = [
            albedo[0] * diffuse[0] + spec_rgb[0],
            albedo[1] * diffuse[1] + spec_rgb[1],
            albedo[2] * diffuse[2] + spec_rgb[2],
        ];
        Shaded { rgb, albedo_luma: 0.3 * albedo[0] + 0.59 * albedo[1] + 0.11 * albedo[2], specular: spec }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shading_is_two_sided_and_patterns_stay_in_range() {
        let l = Lighting { ambient: [0.2; 3], lights: vec![Light { dir: [0.0, 0.0, -1.0], color: [0.8; 3] }] };
        let m = Material::solid([0.5; 3], 0.0);
        let a = l.shade(&m, [0.5; 3], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]).rgb;
        let b = l.shade(&m, [0.5; 3], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]).rgb;
        assert_eq!(a, b);
        assert!((a[0] - 0.5).abs() < 1e-6);
        let mut rng = Rng::new(3);
        for _ in 0..50 {
            let m = Material::random(&mut rng, 1.0);
            let c = m.albedo([rng.uniform() as f32, rng.uniform() as f32, -(rng.uniform() as f32)]);
            assert!(c.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}
