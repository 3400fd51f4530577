//! Triangle meshes and the builders the shape generators use: lathe
//! (surfaces of revolution about y), boxes, rounded prisms, tubes and tori,
//! and normalisation to the NOCS frame (tight box centred, diagonal 1).

use crate::geometry::{Mat3, Vec3};
use std::f64::consts::TAU;

/// Triangle tag of ordinary surfaces.
pub const TAG_NONE: u8 = 0;
/// Triangle tag of a mug's handle (used for `handle_visible`).
pub const TAG_HANDLE: u8 = 1;

/// An indexed triangle mesh with per-vertex normals and, per triangle, a
/// material slot (index into the owner's material list) and a tag.
#[derive(Clone, Debug, Default)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals (orientation is not relied upon: shading is two-sided).
    pub normals: Vec<Vec3>,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Material slot of each triangle.
    pub materials: Vec<u8>,
    /// Tag of each triangle ([`TAG_NONE`], [`TAG_HANDLE`]).
    pub tags: Vec<u8>,
}

/// Axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Vec3,
    /// Maximum corner.
    pub max: Vec3,
}

impl Aabb {
    /// Size along each axis.
    pub fn extents(&self) -> Vec3 {
        self.max - self.min
    }

    /// Centre of the box.
    pub fn center(&self) -> Vec3 {
        (self.max + self.min) * 0.5
    }
}

fn unit_or(v: Vec3, fallback: Vec3) -> Vec3 {
    let n = v.norm();
    if n > 1e-12 { v / n } else { fallback }
}

impl TriMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    fn push_vertex(&mut self, p: Vec3, n: Vec3) -> u32 {
        self.positions.push(p);
        self.normals.push(n);
        (self.positions.len() - 1) as u32
    }

    fn push_tri(&mut self, t: [u32; 3], material: u8, tag: u8) {
        self.triangles.push(t);
        self.materials.push(material);
        self.tags.push(tag);
    }

    /// Appends another mesh.
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        self.normals.extend_from_slice(&other.normals);
        self.triangles.extend(other.triangles.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
        self.materials.extend_from_slice(&other.materials);
        self.tags.extend_from_slice(&other.tags);
    }

    /// Applies `p -> rotation * p + translation` (normals are rotated).
    pub fn transform(&mut self, rotation: &Mat3, translation: &Vec3) {
        for p in &mut self.positions {
            *p = rotation * *p + translation;
        }
        for n in &mut self.normals {
            *n = rotation * *n;
        }
    }

    /// Scales positions uniformly by `s > 0`.
    pub fn scale(&mut self, s: f64) {
        for p in &mut self.positions {
            *p *= s;
        }
    }

    /// The tight axis-aligned box of the vertices (a zero box when empty).
    pub fn aabb(&self) -> Aabb {
        let mut min = Vec3::repeat(f64::INFINITY);
        let mut max = Vec3::repeat(f64::NEG_INFINITY);
        for p in &self.positions {
            min = min.inf(p);
            max = max.sup(p);
        }
        if self.positions.is_empty() {
            return Aabb { min: Vec3::zeros(), max: Vec3::zeros() };
        }
        Aabb { min, max }
    }

    /// Moves the tight box's centre to the origin and scales the box diagonal
    /// to 1 (the NOCS normalisation). Returns the normalised extents.
    pub fn normalize(&mut self) -> Vec3 {
        let b = self.aabb();
        let c = b.center();
        let diag = b.extents().norm();
        let s = if diag > 0.0 { 1.0 / diag } else { 1.0 };
        for p in &mut self.positions {
            *p = (*p - c) * s;
        }
        self.aabb().extents()
    }

    /// Surface of revolution about +y of a profile polyline of (radius, y)
    /// points, `segments` steps around. Normals are smooth along the profile;
    /// build separate lathes where a crease is wanted.
    pub fn lathe(profile: &[[f64; 2]], segments: usize, material: u8, tag: u8) -> TriMesh {
        let mut m = TriMesh::default();
        let n = profile.len();
        if n < 2 || segments < 3 {
            return m;
        }
        // 2D profile normals: perpendicular of the averaged neighbouring tangents.
        let normals2: Vec<[f64; 2]> = (0..n)
            .map(|i| {
                let a = profile[i.saturating_sub(1)];
                let b = profile[(i + 1).min(n - 1)];
                let (dr, dy) = (b[0] - a[0], b[1] - a[1]);
                let len = (dr * dr + dy * dy).sqrt().max(1e-12);
                [dy / len, -dr / len]
            })
            .collect();
        for s in 0..=segments {
            let th = TAU * s as f64 / segments as f64;
            let (sn, cs) = th.sin_cos();
            for (i, q) in profile.iter().enumerate() {
                let nn = normals2[i];
                m.push_vertex(Vec3::new(q[0] * cs, q[1], q[0] * sn), Vec3::new(nn[0] * cs, nn[1], nn[0] * sn));
            }
        }
        let row = n as u32;
        for s in 0..segments as u32 {
            for i in 0..row - 1 {
                let a = s * row + i;
                let b = (s + 1) * row + i;
                m.push_tri([a, b, a + 1], material, tag);
                m.push_tri([a + 1, b, b + 1], material, tag);
            }
        }
        m
    }

    /// An axis-aligned box with flat faces; `materials` gives the slot of the
    /// faces -x, +x, -y, +y, -z, +z.
    pub fn cuboid(min: Vec3, max: Vec3, materials: [u8; 6], tag: u8) -> TriMesh {
        let mut m = TriMesh::default();
        for (axis, side, mat) in [(0, 0, 0usize), (0, 1, 1), (1, 0, 2), (1, 1, 3), (2, 0, 4), (2, 1, 5)]
            .map(|(a, s, k)| (a, s, materials[k]))
        {
            let u = (axis + 1) % 3;
            let v = (axis + 2) % 3;
            let mut normal = Vec3::zeros();
            normal[axis] = if side == 1 { 1.0 } else { -1.0 };
            let fixed = if side == 1 { max[axis] } else { min[axis] };
            let mut idx = [0u32; 4];
            for (k, (du, dv)) in [(0, 0), (1, 0), (1, 1), (0, 1)].into_iter().enumerate() {
                let mut p = Vec3::zeros();
                p[axis] = fixed;
                p[u] = if du == 1 { max[u] } else { min[u] };
                p[v] = if dv == 1 { max[v] } else { min[v] };
                idx[k] = m.push_vertex(p, normal);
            }
            m.push_tri([idx[0], idx[1], idx[2]], mat, tag);
            m.push_tri([idx[0], idx[2], idx[3]], mat, tag);
        }
        m
    }

    /// A prism: the convex polygon `outline` in the xy plane extruded from
    /// z0 to z1, with smooth side normals and flat caps.
    pub fn prism(outline: &[[f64; 2]], z0: f64, z1: f64, side_mat: u8, back_mat: u8, front_mat: u8) -> TriMesh {
        let mut m = TriMesh::default();
        let n = outline.len();
        if n < 3 {
            return m;
        }
        let mut side = Vec::with_capacity(n);
        for i in 0..n {
            let a = outline[(i + n - 1) % n];
            let b = outline[(i + 1) % n];
            let tn = Vec3::new(b[1] - a[1], -(b[0] - a[0]), 0.0);
            side.push(unit_or(tn, Vec3::x()));
        }
        let base = m.positions.len() as u32;
        for (i, q) in outline.iter().enumerate() {
            m.push_vertex(Vec3::new(q[0], q[1], z0), side[i]);
            m.push_vertex(Vec3::new(q[0], q[1], z1), side[i]);
        }
        for i in 0..n as u32 {
            let j = (i + 1) % n as u32;
            let (a0, a1, b0, b1) = (base + 2 * i, base + 2 * i + 1, base + 2 * j, base + 2 * j + 1);
            m.push_tri([a0, b0, b1], side_mat, TAG_NONE);
            m.push_tri([a0, b1, a1], side_mat, TAG_NONE);
        }
        let cen = outline.iter().fold([0.0, 0.0], |acc, q| [acc[0] + q[0], acc[1] + q[1]]);
        let cen = [cen[0] / n as f64, cen[1] / n as f64];
        for (z, normal, mat) in [(z0, -Vec3::z(), back_mat), (z1, Vec3::z(), front_mat)] {
            let c = m.push_vertex(Vec3::new(cen[0], cen[1], z), normal);
            let first = m.positions.len() as u32;
            for q in outline {
                m.push_vertex(Vec3::new(q[0], q[1], z), normal);
            }
            for i in 0..n as u32 {
                m.push_tri([c, first + i, first + (i + 1) % n as u32], mat, TAG_NONE);
            }
        }
        m
    }

    /// A tube of circular cross-section `radius` along the polyline `path`
    /// (open ends), `sides` vertices around.
    pub fn tube(path: &[Vec3], radius: f64, sides: usize, closed: bool, material: u8, tag: u8) -> TriMesh {
        let mut m = TriMesh::default();
        let n = path.len();
        if n < 2 || sides < 3 {
            return m;
        }
        let tangent = |i: usize| -> Vec3 {
            let (a, b) = if closed {
                (path[(i + n - 1) % n], path[(i + 1) % n])
            } else {
                (path[i.saturating_sub(1)], path[(i + 1).min(n - 1)])
            };
            unit_or(b - a, Vec3::y())
        };
        // Parallel-transported frame.
        let t0 = tangent(0);
        let helper = if t0.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
        let mut u = unit_or(t0.cross(&helper), Vec3::z());
        for (i, &centre) in path.iter().enumerate() {
            let t = tangent(i);
            u = unit_or(u - t * u.dot(&t), u);
            let v = t.cross(&u);
            for k in 0..sides {
                let a = TAU * k as f64 / sides as f64;
                let dir = u * a.cos() + v * a.sin();
                m.push_vertex(centre + dir * radius, dir);
            }
        }
        let rings = if closed { n } else { n - 1 };
        let s = sides as u32;
        for i in 0..rings as u32 {
            let j = (i + 1) % n as u32;
            for k in 0..s {
                let k2 = (k + 1) % s;
                let (a, b, c, d) = (i * s + k, i * s + k2, j * s + k, j * s + k2);
                m.push_tri([a, c, d], material, tag);
                m.push_tri([a, d, b], material, tag);
            }
        }
        m
    }

    /// A torus about +y with major radius `major`, tube radius `minor`.
    pub fn torus(major: f64, minor: f64, segments: usize, sides: usize, material: u8) -> TriMesh {
        let path: Vec<Vec3> = (0..segments)
            .map(|i| {
                let a = TAU * i as f64 / segments as f64;
                Vec3::new(major * a.cos(), 0.0, major * a.sin())
            })
            .collect();
        TriMesh::tube(&path, minor, sides, true, material, TAG_NONE)
    }

    /// A sphere of `radius` centred at the origin.
    pub fn sphere(radius: f64, segments: usize, material: u8) -> TriMesh {
        let rings = segments / 2;
        let profile: Vec<[f64; 2]> = (0..=rings)
            .map(|i| {
                let a = std::f64::consts::PI * i as f64 / rings as f64;
                [radius * a.sin(), -radius * a.cos()]
            })
            .collect();
        TriMesh::lathe(&profile, segments, material, TAG_NONE)
    }

    /// A closed cylinder about +y from y0 to y1 (three smooth pieces: bottom, side, top).
    pub fn cylinder(radius: f64, y0: f64, y1: f64, segments: usize, side_mat: u8, cap_mat: u8) -> TriMesh {
        let mut m = TriMesh::lathe(&[[0.0, y0], [radius, y0]], segments, cap_mat, TAG_NONE);
        m.append(&TriMesh::lathe(&[[radius, y0], [radius, y1]], segments, side_mat, TAG_NONE));
        m.append(&TriMesh::lathe(&[[radius, y1], [0.0, y1]], segments, cap_mat, TAG_NONE));
        m
    }
}

/// Points of a rounded rectangle of half sizes (hx, hy) and corner radius r,
/// counter-clockwise, `per_corner` points per corner arc.
pub fn rounded_rect(hx: f64, hy: f64, r: f64, per_corner: usize) -> Vec<[f64; 2]> {
    let r = r.clamp(0.0, hx.min(hy) * 0.999);
    let mut pts = Vec::new();
    let corners =
        [(hx - r, hy - r, 0.0), (-(hx - r), hy - r, 0.25), (-(hx - r), -(hy - r), 0.5), (hx - r, -(hy - r), 0.75)];
    for (cx, cy, start) in corners {
        for k in 0..=per_corner.max(1) {
            let a = TAU * (start + 0.25 * k as f64 / per_corner.max(1) as f64);
            pts.push([cx + r * a.cos(), cy + r * a.sin()]);
        }
    }
    pts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalize_gives_unit_diagonal_centred_box() {
        let mut m = TriMesh::cylinder(0.3, 0.1, 2.0, 24, 0, 0);
        let e = m.normalize();
        let b = m.aabb();
        assert!((e.norm() - 1.0).abs() < 1e-12);
        assert!(b.center().norm() < 1e-12);
        assert!((e.x - e.z).abs() < 1e-12);
        assert!(m.normals.iter().all(|n| (n.norm() - 1.0).abs() < 1e-9));
    }

    #[test]
    fn builders_produce_consistent_buffers() {
        let mut m = TriMesh::cuboid(Vec3::zeros(), Vec3::repeat(1.0), [0, 1, 2, 3, 4, 5], 0);
        m.append(&TriMesh::torus(1.0, 0.2, 16, 8, 1));
        m.append(&TriMesh::prism(&rounded_rect(1.0, 0.5, 0.1, 3), 0.0, 1.0, 0, 1, 2));
        m.append(&TriMesh::sphere(1.0, 16, 0));
        assert_eq!(m.triangles.len(), m.materials.len());
        assert_eq!(m.triangles.len(), m.tags.len());
        assert_eq!(m.positions.len(), m.normals.len());
        assert!(m.triangles.iter().flatten().all(|&i| (i as usize) < m.positions.len()));
    }
}
