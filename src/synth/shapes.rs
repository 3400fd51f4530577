//! Per-category procedural object generators. Each builds a mesh in nominal
//! units, normalises it to the NOCS frame (y up, tight box centred, diagonal
//! 1) and samples a metric scale from a realistic size range.

use super::mesh::{TAG_HANDLE, TAG_NONE, TriMesh, rounded_rect};
use super::shading::{Material, Pattern, hsv, random_color};
use crate::category::Category;
use crate::geometry::{Vec3, rotation_axis_angle};
use crate::rng::Rng;
use std::f64::consts::{FRAC_PI_2, PI};

/// Segments around surfaces of revolution.
pub const LATHE_SEGMENTS: usize = 48;

/// Bottle height range, metres.
pub const BOTTLE_HEIGHT_M: (f64, f64) = (0.15, 0.32);
/// Bowl diameter range, metres.
pub const BOWL_DIAMETER_M: (f64, f64) = (0.12, 0.22);
/// Camera body width range, metres.
pub const CAMERA_WIDTH_M: (f64, f64) = (0.09, 0.16);
/// Can height range, metres.
pub const CAN_HEIGHT_M: (f64, f64) = (0.09, 0.17);
/// Laptop width range, metres.
pub const LAPTOP_WIDTH_M: (f64, f64) = (0.28, 0.45);
/// Mug height range, metres.
pub const MUG_HEIGHT_M: (f64, f64) = (0.08, 0.13);
/// Laptop lid opening angle range from the base, degrees.
pub const LAPTOP_OPENING_DEG: (f64, f64) = (70.0, 130.0);

/// A generated object: its canonical (normalised) mesh and metric scale.
#[derive(Clone, Debug)]
pub struct ObjectModel {
    /// Category.
    pub category: Category,
    /// Mesh in the NOCS frame: tight box centred at 0, diagonal 1.
    pub mesh: TriMesh,
    /// Normalised box extents (x, y, z); their norm is 1.
    pub extents: Vec3,
    /// Metres per normalised unit (= box diagonal in metres = |size_m|).
    pub scale: f64,
    /// Materials indexed by the mesh's material slots.
    pub materials: Vec<Material>,
    /// Texture coordinates are `local / tex_scale + tex_offset` (the nominal
    /// units the generator used, so labels stay where they were designed).
    pub tex_scale: f64,
    /// See `tex_scale`.
    pub tex_offset: Vec3,
}

impl ObjectModel {
    /// Metric box size along x, y, z (the GT `size_m`).
    pub fn size_m(&self) -> [f64; 3] {
        [self.extents.x * self.scale, self.extents.y * self.scale, self.extents.z * self.scale]
    }
}

/// Generates a random instance of `category`.
pub fn generate_object(category: Category, rng: &mut Rng) -> ObjectModel {
    let (mesh, materials, target) = match category {
        Category::Bottle => bottle(rng),
        Category::Bowl => bowl(rng),
        Category::Camera => camera(rng),
        Category::Can => can(rng),
        Category::Laptop => laptop(rng),
        Category::Mug => mug(rng),
    };
    finish(category, mesh, materials, target)
}

/// Which nominal dimension a metric target refers to.
enum Target {
    /// Box height (y) in metres.
    Height(f64),
    /// Box width (x extent of the revolved part, i.e. the diameter) in metres.
    Width(f64),
}

fn finish(category: Category, mut mesh: TriMesh, materials: Vec<Material>, target: Target) -> ObjectModel {
    let b = mesh.aabb();
    let c = b.center();
    let diag = b.extents().norm();
    let extents = mesh.normalize();
    let scale = match target {
        Target::Height(h) => h / extents.y,
        Target::Width(w) => w / extents.x,
    };
    ObjectModel { category, mesh, extents, scale, materials, tex_scale: 1.0 / diag, tex_offset: c }
}

fn glass_or_plastic(rng: &mut Rng) -> Material {
    let base = match rng.below(4) {
        0 => [0.12, 0.35, 0.15],
        1 => [0.35, 0.2, 0.08],
        2 => [0.55, 0.65, 0.7],
        _ => random_color(rng),
    };
    let jitter = |v: f32, r: &mut Rng| (v * r.range(0.8, 1.2) as f32).clamp(0.0, 1.0);
    let base = [jitter(base[0], rng), jitter(base[1], rng), jitter(base[2], rng)];
    Material { base, alt: base, pattern: Pattern::Solid, specular: rng.range(0.3, 0.7) as f32, shininess: 48.0 }
}

fn label(rng: &mut Rng, body: Material, y0: f64, y1: f64) -> Material {
    Material {
        base: body.base,
        alt: random_color(rng),
        pattern: Pattern::Band { y0: y0 as f32, y1: y1 as f32, freq: rng.range(4.0, 16.0) as f32 },
        specular: body.specular,
        shininess: body.shininess,
    }
}

/// Bottle: nominal height 1; body, shoulder (round to conical), neck, cap.
fn bottle(rng: &mut Rng) -> (TriMesh, Vec<Material>, Target) {
    let r = rng.range(0.11, 0.23);
    let rn = r * rng.range(0.22, 0.6);
    let hc = rng.range(0.035, 0.1);
    let rc = rn * rng.range(1.0, 1.35);
    let ln = rng.range(0.03, 0.28);
    let ls = rng.range(0.05, 0.25);
    let hb = 1.0 - hc - ln - ls;
    let a = rng.range(0.6, 2.5);
    let bevel = 0.02f64.min(r * 0.3);
    let mut side = vec![[r - bevel, 0.0], [r, bevel], [r, hb]];
    for k in 1..=10 {
        let t = f64::from(k) / 10.0;
        let g = (1.0 - t.powf(a)).max(0.0).powf(1.0 / a);
        side.push([rn + (r - rn) * g, hb + ls * t]);
    }
    let yn = hb + ls + ln;
    side.push([rn, yn]);
    let mut m = TriMesh::lathe(&[[0.0, 0.0], [r - bevel, 0.0]], LATHE_SEGMENTS, 0, TAG_NONE);
    m.append(&TriMesh::lathe(&side, LATHE_SEGMENTS, 0, TAG_NONE));
    m.append(&TriMesh::lathe(&[[rn, yn], [rc, yn]], LATHE_SEGMENTS, 1, TAG_NONE));
    m.append(&TriMesh::lathe(&[[rc, yn], [rc, 1.0]], LATHE_SEGMENTS, 1, TAG_NONE));
    m.append(&TriMesh::lathe(&[[rc, 1.0], [0.0, 1.0]], LATHE_SEGMENTS, 1, TAG_NONE));
    let body = glass_or_plastic(rng);
    let body = if rng.chance(0.8) {
        let y0 = hb * rng.range(0.1, 0.4);
        let y1 = y0 + hb * rng.range(0.25, 0.55);
        label(rng, body, y0, y1)
    } else {
        body
    };
    let cap = Material::solid(random_color(rng), 0.2);
    (m, vec![body, cap], Target::Height(rng.range(BOTTLE_HEIGHT_M.0, BOTTLE_HEIGHT_M.1)))
}

/// Bowl: nominal rim radius 1; flat bottom, curved wall (hemispherical to
/// flat, optionally flared), rounded rim, inner surface at wall thickness t.
fn bowl(rng: &mut Rng) -> (TriMesh, Vec<Material>, Target) {
    let h = rng.range(0.3, 0.8);
    let rb = rng.range(0.15, 0.55);
    let t = rng.range(0.03, 0.07);
    let phi_max = rng.range(1.15, FRAC_PI_2);
    let steps = 14;
    let (smax, cmax) = (phi_max.sin(), 1.0 - phi_max.cos());
    let mut outer = vec![[0.0, 0.0]];
    for k in 0..=steps {
        let phi = phi_max * f64::from(k) / f64::from(steps);
        outer.push([rb + (1.0 - rb) * phi.sin() / smax, h * (1.0 - phi.cos()) / cmax]);
    }
    let mut inner = Vec::new();
    for k in 0..=6 {
        let a = PI * f64::from(k) / 6.0;
        inner.push([1.0 - t * 0.5 + t * 0.5 * a.cos(), h + t * 0.5 * a.sin()]);
    }
    let rbi = (rb - t).max(0.0);
    for k in (0..steps).rev() {
        let phi = phi_max * f64::from(k) / f64::from(steps);
        inner.push([rbi + (1.0 - t - rbi) * phi.sin() / smax, t + (h - t) * (1.0 - phi.cos()) / cmax]);
    }
    inner.push([0.0, t]);
    let mut m = TriMesh::lathe(&outer, LATHE_SEGMENTS, 0, TAG_NONE);
    m.append(&TriMesh::lathe(&inner, LATHE_SEGMENTS, 1, TAG_NONE));
    let out = Material::random(rng, 0.5);
    let inside = if rng.chance(0.5) { Material::solid(random_color(rng), out.specular) } else { out };
    (m, vec![out, inside], Target::Width(rng.range(BOWL_DIAMETER_M.0, BOWL_DIAMETER_M.1)))
}

/// Can: nominal radius 1; domed bottom, rims, straight labelled side, optional
/// necked top, recessed tab-less lid.
fn can(rng: &mut Rng) -> (TriMesh, Vec<Material>, Target) {
    let h = rng.range(1.5, 4.2);
    let necked = rng.chance(0.6);
    let s = LATHE_SEGMENTS;
    let mut m = TriMesh::lathe(&[[0.0, 0.07], [0.5, 0.05], [0.8, 0.02], [0.86, 0.0]], s, 1, TAG_NONE);
    m.append(&TriMesh::lathe(&[[0.86, 0.0], [0.96, 0.04], [1.0, 0.12]], s, 1, TAG_NONE));
    let top_side = if necked { h - 0.3 } else { h - 0.06 };
    m.append(&TriMesh::lathe(&[[1.0, 0.12], [1.0, top_side]], s, 0, TAG_NONE));
    let lid_r = if necked {
        m.append(&TriMesh::lathe(&[[1.0, top_side], [0.95, h - 0.15], [0.9, h - 0.05], [0.92, h]], s, 1, TAG_NONE));
        0.92
    } else {
        m.append(&TriMesh::lathe(&[[1.0, top_side], [1.02, h - 0.03], [1.0, h]], s, 1, TAG_NONE));
        1.0
    };
    let lid_in = lid_r - 0.07;
    m.append(&TriMesh::lathe(&[[lid_r, h], [lid_in, h - 0.02], [lid_in - 0.01, h - 0.07]], s, 1, TAG_NONE));
    m.append(&TriMesh::lathe(&[[lid_in - 0.01, h - 0.07], [0.0, h - 0.07]], s, 1, TAG_NONE));
    let metal = Material::solid([0.72, 0.73, 0.75], 0.6);
    let body = Material::random(rng, 0.3);
    let y0 = 0.12 + (top_side - 0.12) * rng.range(0.0, 0.3);
    let y1 = y0 + (top_side - y0) * rng.range(0.4, 1.0);
    let body = if rng.chance(0.7) { label(rng, body, y0, y1) } else { body };
    let body = Material { specular: rng.range(0.2, 0.6) as f32, ..body };
    (m, vec![body, metal], Target::Height(rng.range(CAN_HEIGHT_M.0, CAN_HEIGHT_M.1)))
}

/// Mug: nominal height 1; cylindrical or tapered wall with thickness, open
/// top with rounded rim, and a handle (a tube on an elliptic arc) at +x.
fn mug(rng: &mut Rng) -> (TriMesh, Vec<Material>, Target) {
    let r = rng.range(0.34, 0.56);
    let taper = if rng.chance(0.5) { 0.0 } else { rng.range(-0.08, 0.1) };
    let (rt, rb) = (r * (1.0 + taper), r * (1.0 - taper));
    let t = rng.range(0.035, 0.075);
    let tb = rng.range(0.05, 0.1);
    let s = LATHE_SEGMENTS;
    let bev = 0.03;
    let mut m = TriMesh::lathe(&[[0.0, 0.0], [rb - bev, 0.0]], s, 0, TAG_NONE);
    let mut outer = vec![[rb - bev, 0.0], [rb, bev], [rt, 1.0]];
    for k in 1..=6 {
        let a = PI * f64::from(k) / 6.0;
        outer.push([rt - t * 0.5 + t * 0.5 * a.cos(), 1.0 + t * 0.5 * a.sin()]);
    }
    m.append(&TriMesh::lathe(&outer, s, 0, TAG_NONE));
    let inner = [[rt - t, 1.0], [rb - t, tb + 0.04], [rb - t - 0.04, tb], [0.0, tb]];
    m.append(&TriMesh::lathe(&inner, s, 1, TAG_NONE));
    // Handle: elliptic arc in the xy plane, ends sunk half a wall into the body.
    let theta_e = rng.range(1.75, 2.2);
    let ay = rng.range(0.2, 0.34);
    let ax = rng.range(0.14, 0.3);
    let yc = rng.range(0.45, 0.56);
    let b = rng.range(0.03, 0.06);
    let ends_y = [yc - ay * theta_e.sin(), yc + ay * theta_e.sin()];
    let r_at = |y: f64| rb + (rt - rb) * y;
    let r_attach = r_at(ends_y[0]).min(r_at(ends_y[1])) - 0.5 * t;
    let xc = r_attach - ax * theta_e.cos();
    let path: Vec<Vec3> = (0..=24)
        .map(|k| {
            let th = -theta_e + 2.0 * theta_e * f64::from(k) / 24.0;
            Vec3::new(xc + ax * th.cos(), yc + ay * th.sin(), 0.0)
        })
        .collect();
    m.append(&TriMesh::tube(&path, b, 12, false, 2, TAG_HANDLE));
    let body = Material::random(rng, 0.35);
    let inside = if rng.chance(0.5) { Material::solid(random_color(rng), body.specular) } else { body };
    let handle = if rng.chance(0.8) { body } else { Material::solid(random_color(rng), body.specular) };
    (m, vec![body, inside, handle], Target::Height(rng.range(MUG_HEIGHT_M.0, MUG_HEIGHT_M.1)))
}

/// Laptop: nominal width 1; base box in the xz plane at the bottom, hinge
/// along x at the back (-z), lid box opened by 70-130 degrees.
fn laptop(rng: &mut Rng) -> (TriMesh, Vec<Material>, Target) {
    let d = rng.range(0.62, 0.75);
    let tb = rng.range(0.02, 0.045);
    let tl = rng.range(0.012, 0.025);
    let alpha = rng.range(LAPTOP_OPENING_DEG.0, LAPTOP_OPENING_DEG.1).to_radians();
    // slots: 0 shell, 1 keyboard deck, 2 screen
    let mut m =
        TriMesh::cuboid(Vec3::new(-0.5, 0.0, -d / 2.0), Vec3::new(0.5, tb, d / 2.0), [0, 0, 0, 1, 0, 0], TAG_NONE);
    let mut lid = TriMesh::cuboid(Vec3::new(-0.5, 0.0, 0.0), Vec3::new(0.5, tl, d), [0, 0, 2, 0, 0, 0], TAG_NONE);
    // Lid-local (x, thickness, length) -> object: columns ex, n, u.
    let rot = rotation_axis_angle(&Vec3::x(), -alpha);
    lid.transform(&rot, &Vec3::new(0.0, tb, -d / 2.0));
    m.append(&lid);
    let shell = if rng.chance(0.6) {
        let g = rng.range(0.1, 0.8) as f32;
        Material::solid([g, g, g * 1.02], 0.3)
    } else {
        Material::solid(random_color(rng), 0.3)
    };
    let dark = rng.range(0.03, 0.15) as f32;
    let keys = Material {
        base: shell.base,
        alt: [dark, dark, dark],
        pattern: Pattern::Checker { freq: rng.range(40.0, 70.0) as f32 },
        specular: 0.1,
        shininess: 16.0,
    };
    let screen_col = if rng.chance(0.6) { [0.03, 0.03, 0.05] } else { hsv(rng.uniform() as f32, 0.6, 0.5) };
    let screen = Material {
        base: screen_col,
        alt: [0.02, 0.02, 0.02],
        pattern: Pattern::Noise { freq: rng.range(3.0, 10.0) as f32 },
        specular: 0.6,
        shininess: 64.0,
    };
    (m, vec![shell, keys, screen], Target::Width(rng.range(LAPTOP_WIDTH_M.0, LAPTOP_WIDTH_M.1)))
}

/// Camera: nominal body width 1; rounded/chamfered body box, lens
/// cylinder(s) along +z, optional viewfinder hump, flash and grip.
fn camera(rng: &mut Rng) -> (TriMesh, Vec<Material>, Target) {
    let hc = rng.range(0.55, 0.8);
    let dc = rng.range(0.3, 0.55);
    let corner = rng.range(0.02, 0.16) * hc;
    let per_corner = if rng.chance(0.3) { 1 } else { 4 }; // chamfer or round
    // slots: 0 body, 1 lens barrel, 2 glass, 3 accent
    let mut m = TriMesh::prism(&rounded_rect(0.5, hc / 2.0, corner, per_corner), -dc / 2.0, dc / 2.0, 0, 0, 0);
    let to_z = rotation_axis_angle(&Vec3::x(), FRAC_PI_2);
    let rl = hc * rng.range(0.22, 0.42);
    let xl = rng.range(-0.08, 0.12);
    let yl = rng.range(-0.08, 0.04) * hc;
    let l1 = rng.range(0.12, 0.7);
    let r2 = rl * rng.range(0.8, 1.12);
    let l2 = rng.range(0.04, 0.14);
    let z0 = dc / 2.0;
    let mut lens = TriMesh::lathe(&[[rl, 0.0], [rl, l1]], LATHE_SEGMENTS, 1, TAG_NONE);
    lens.append(&TriMesh::lathe(&[[rl, l1], [r2, l1]], LATHE_SEGMENTS, 1, TAG_NONE));
    lens.append(&TriMesh::lathe(&[[r2, l1], [r2, l1 + l2]], LATHE_SEGMENTS, 3, TAG_NONE));
    lens.append(&TriMesh::lathe(&[[r2, l1 + l2], [r2 * 0.8, l1 + l2]], LATHE_SEGMENTS, 1, TAG_NONE));
    lens.append(&TriMesh::lathe(&[[r2 * 0.8, l1 + l2 - 0.01], [0.0, l1 + l2 - 0.03]], LATHE_SEGMENTS, 2, TAG_NONE));
    // lathe axis +y -> +z, then move to the front face
    lens.transform(&to_z, &Vec3::new(xl, yl, z0 - 0.005));
    m.append(&lens);
    let top = hc / 2.0;
    if rng.chance(0.5) {
        let w = rng.range(0.22, 0.36);
        let hh = rng.range(0.1, 0.2) * hc;
        let x = xl + rng.range(-0.05, 0.05);
        m.append(&TriMesh::cuboid(
            Vec3::new(x - w / 2.0, top - 0.01, -dc * 0.35),
            Vec3::new(x + w / 2.0, top + hh, dc * 0.3),
            [0; 6],
            TAG_NONE,
        ));
    }
    if rng.chance(0.4) {
        let x = rng.range(-0.42, -0.25);
        m.append(&TriMesh::cuboid(
            Vec3::new(x - 0.07, top - 0.01, dc * 0.1),
            Vec3::new(x + 0.07, top + 0.06, dc * 0.45),
            [3; 6],
            TAG_NONE,
        ));
    }
    if rng.chance(0.5) {
        let gz = rng.range(0.06, 0.18);
        m.append(&TriMesh::cuboid(
            Vec3::new(-0.5, -hc * 0.45, 0.0),
            Vec3::new(-0.5 + rng.range(0.14, 0.24), hc * 0.4, dc / 2.0 + gz),
            [0; 6],
            TAG_NONE,
        ));
    }
    let body = if rng.chance(0.5) {
        let g = rng.range(0.03, 0.2) as f32;
        Material::solid([g, g, g], 0.3)
    } else {
        Material::random(rng, 0.2)
    };
    let barrel = Material::solid([0.05, 0.05, 0.06], 0.3);
    let glass = Material::solid([0.02, 0.03, 0.06], 0.8);
    let accent = Material::solid(random_color(rng), 0.4);
    (m, vec![body, barrel, glass, accent], Target::Width(rng.range(CAMERA_WIDTH_M.0, CAMERA_WIDTH_M.1)))
}
