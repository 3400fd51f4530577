//! The z-buffer rasterizer: a visibility pass (triangle id and 1/z per pixel,
//! fixed-point edge functions with a top-left style tie rule, near-plane
//! clipping), then a resolve pass that intersects each pixel's ray with its
//! triangle exactly (perspective-correct barycentrics, exact depth) and fills
//! the G-buffer (depth, item, NOCS, handle tag, shaded colour).

use super::mesh::TAG_HANDLE;
use super::scene::Scene;
use super::shading::Material;
use crate::frame::Intrinsics;

/// Near clipping plane, metres.
pub const NEAR_M: f32 = 0.02;
/// Sub-pixel precision of the fixed-point rasterizer (steps per pixel).
const SUBPIX: f32 = 16.0;
/// Screen coordinates beyond this many pixels are not rasterized (guard).
const MAX_SCREEN_PX: f32 = 1.0e6;
/// "No triangle" in the visibility buffer.
const NO_TRI: u32 = u32::MAX;
/// "No item" in the G-buffer.
pub const NO_ITEM: u16 = u16::MAX;

/// The scene flattened into camera-frame triangle soup.
pub struct Geometry {
    pos: Vec<[f32; 3]>,
    nrm: Vec<[f32; 3]>,
    tex: Vec<[f32; 3]>,
    nocs: Vec<[f32; 3]>,
    tris: Vec<[u32; 3]>,
    tri_item: Vec<u16>,
    tri_mat: Vec<u16>,
    tri_tag: Vec<u8>,
    materials: Vec<Material>,
}

impl Geometry {
    /// Transforms every item into the camera frame.
    pub fn build(scene: &Scene) -> Geometry {
        let nv: usize = scene.items.iter().map(|it| it.mesh.positions.len()).sum();
        let nt: usize = scene.items.iter().map(|it| it.mesh.triangles.len()).sum();
        let mut g = Geometry {
            pos: Vec::with_capacity(nv),
            nrm: Vec::with_capacity(nv),
            tex: Vec::with_capacity(nv),
            nocs: Vec::with_capacity(nv),
            tris: Vec::with_capacity(nt),
            tri_item: Vec::with_capacity(nt),
            tri_mat: Vec::with_capacity(nt),
            tri_tag: Vec::with_capacity(nt),
            materials: Vec::new(),
        };
        for (k, it) in scene.items.iter().enumerate() {
            let base = g.pos.len() as u32;
            let mat_base = g.materials.len() as u16;
            g.materials.extend_from_slice(&it.materials);
            let r = it.camera_from_local.rotation;
            let t = it.camera_from_local.translation_m;
            let inv_tex = 1.0 / it.tex_scale;
            for (p, n) in it.mesh.positions.iter().zip(&it.mesh.normals) {
                let c = r * (p * it.scale) + t;
                let nn = r * n;
                let tx = p * inv_tex + it.tex_offset;
                g.pos.push([c.x as f32, c.y as f32, c.z as f32]);
                g.nrm.push([nn.x as f32, nn.y as f32, nn.z as f32]);
                g.tex.push([tx.x as f32, tx.y as f32, tx.z as f32]);
                if it.object.is_some() {
                    g.nocs.push([(p.x + 0.5) as f32, (p.y + 0.5) as f32, (p.z + 0.5) as f32]);
                } else {
                    g.nocs.push([0.0; 3]);
                }
            }
            for (i, tri) in it.mesh.triangles.iter().enumerate() {
                g.tris.push([tri[0] + base, tri[1] + base, tri[2] + base]);
                g.tri_item.push(k as u16);
                let slot = usize::from(it.mesh.materials[i]).min(it.materials.len().saturating_sub(1));
                g.tri_mat.push(mat_base + slot as u16);
                g.tri_tag.push(it.mesh.tags[i]);
            }
        }
        g
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }
}

/// Per-pixel results of rendering.
pub struct GBuffer {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Exact z of the visible surface in metres (0 where nothing was hit).
    pub depth_m: Vec<f32>,
    /// Index of the visible item ([`NO_ITEM`] where nothing was hit).
    pub item: Vec<u16>,
    /// NOCS coordinate of the visible surface point (objects only; 0 elsewhere).
    pub nocs: Vec<[f32; 3]>,
    /// Whether the visible triangle is a mug handle.
    pub handle: Vec<bool>,
    /// Shaded colour, [0, 1] nominal.
    pub color: Vec<[f32; 3]>,
    /// Albedo luminance.
    pub albedo_luma: Vec<f32>,
    /// Specular highlight strength.
    pub specular: Vec<f32>,
}

struct VisBuffer {
    width: usize,
    height: usize,
    inv_z: Vec<f32>,
    tri: Vec<u32>,
}

#[inline]
fn owns_edge(dx: i64, dy: i64) -> bool {
    dy < 0 || (dy == 0 && dx > 0)
}

impl VisBuffer {
    /// Rasterizes one screen-space triangle (x, y in pixels, 1/z).
    fn raster(&mut self, v: [[f32; 3]; 3], id: u32) {
        for p in &v {
            if !(p[0].abs() < MAX_SCREEN_PX && p[1].abs() < MAX_SCREEN_PX) {
                return;
            }
        }
        let fx = |f: f32| (f * SUBPIX).round() as i64;
        let mut x = [fx(v[0][0]), fx(v[1][0]), fx(v[2][0])];
        let mut y = [fx(v[0][1]), fx(v[1][1]), fx(v[2][1])];
        let mut iz = [v[0][2], v[1][2], v[2][2]];
        let mut area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0]);
        if area == 0 {
            return;
        }
        if area < 0 {
            x.swap(1, 2);
            y.swap(1, 2);
            iz.swap(1, 2);
            area = -area;
        }
        let s = SUBPIX as i64;
        let min_x = (x.iter().min().copied().unwrap_or(0) + s - 1).div_euclid(s).max(0);
        let max_x = x.iter().max().copied().unwrap_or(-1).div_euclid(s).min(self.width as i64 - 1);
        let min_y = (y.iter().min().copied().unwrap_or(0) + s - 1).div_euclid(s).max(0);
        let max_y = y.iter().max().copied().unwrap_or(-1).div_euclid(s).min(self.height as i64 - 1);
        if min_x > max_x || min_y > max_y {
            return;
        }
        // Edge e_k is opposite vertex k: e0 = (1 -> 2), e1 = (2 -> 0), e2 = (0 -> 1).
        let edges = [(1usize, 2usize), (2, 0), (0, 1)];
        let mut step_x = [0i64; 3];
        let mut step_y = [0i64; 3];
        let mut row = [0i64; 3];
        let px0 = min_x * s;
        let py0 = min_y * s;
        for (k, &(a, b)) in edges.iter().enumerate() {
            let (dx, dy) = (x[b] - x[a], y[b] - y[a]);
            let bias = if owns_edge(dx, dy) { 0 } else { -1 };
            row[k] = dx * (py0 - y[a]) - dy * (px0 - x[a]) + bias;
            step_x[k] = -dy * s;
            step_y[k] = dx * s;
        }
        let inv_area = 1.0 / area as f32;
        let (d1, d2) = (iz[1] - iz[0], iz[2] - iz[0]);
        for py in min_y..=max_y {
            let mut e = row;
            let line = py as usize * self.width;
            for px in min_x..=max_x {
                if (e[0] | e[1] | e[2]) >= 0 {
                    // Undo the bias for the weights (it is at most one unit).
                    let l1 = e[1] as f32 * inv_area;
                    let l2 = e[2] as f32 * inv_area;
                    let z = iz[0] + l1 * d1 + l2 * d2;
                    let i = line + px as usize;
                    if z > self.inv_z[i] {
                        self.inv_z[i] = z;
                        self.tri[i] = id;
                    }
                }
                e[0] += step_x[0];
                e[1] += step_x[1];
                e[2] += step_x[2];
            }
            row[0] += step_y[0];
            row[1] += step_y[1];
            row[2] += step_y[2];
        }
    }
}

fn project(k: &Intrinsics, p: [f32; 3]) -> [f32; 3] {
    let iz = 1.0 / p[2];
    [(k.fx as f32) * p[0] * iz + k.cx as f32, (k.fy as f32) * p[1] * iz + k.cy as f32, iz]
}

fn lerp(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
}

fn visibility(g: &Geometry, k: &Intrinsics) -> VisBuffer {
    let (w, h) = (k.width as usize, k.height as usize);
    let mut vb = VisBuffer { width: w, height: h, inv_z: vec![0.0; w * h], tri: vec![NO_TRI; w * h] };
    let screen: Vec<[f32; 3]> =
        g.pos.iter().map(|&p| if p[2] >= NEAR_M { project(k, p) } else { [0.0, 0.0, 0.0] }).collect();
    for (id, t) in g.tris.iter().enumerate() {
        let p = [g.pos[t[0] as usize], g.pos[t[1] as usize], g.pos[t[2] as usize]];
        let inside = [p[0][2] >= NEAR_M, p[1][2] >= NEAR_M, p[2][2] >= NEAR_M];
        if inside[0] && inside[1] && inside[2] {
            vb.raster([screen[t[0] as usize], screen[t[1] as usize], screen[t[2] as usize]], id as u32);
            continue;
        }
        if !(inside[0] || inside[1] || inside[2]) {
            continue;
        }
        // Sutherland-Hodgman against z >= NEAR_M.
        let mut poly: [[f32; 3]; 4] = [[0.0; 3]; 4];
        let mut n = 0;
        for i in 0..3 {
            let (a, b) = (p[i], p[(i + 1) % 3]);
            let (ia, ib) = (inside[i], inside[(i + 1) % 3]);
            if ia {
                poly[n] = a;
                n += 1;
            }
            if ia != ib {
                let tpar = (NEAR_M - a[2]) / (b[2] - a[2]);
                let mut c = lerp(a, b, tpar);
                c[2] = NEAR_M;
                poly[n] = c;
                n += 1;
            }
        }
        let sp: Vec<[f32; 3]> = poly[..n].iter().map(|&q| project(k, q)).collect();
        for j in 1..n.saturating_sub(1) {
            vb.raster([sp[0], sp[j], sp[j + 1]], id as u32);
        }
    }
    vb
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn to64(a: [f32; 3]) -> [f64; 3] {
    [f64::from(a[0]), f64::from(a[1]), f64::from(a[2])]
}
fn interp(v: [[f32; 3]; 3], b: [f32; 3]) -> [f32; 3] {
    [
        v[0][0] * b[0] + v[1][0] * b[1] + v[2][0] * b[2],
        v[0][1] * b[0] + v[1][1] * b[1] + v[2][1] * b[2],
        v[0][2] * b[0] + v[1][2] * b[1] + v[2][2] * b[2],
    ]
}

/// Renders the scene: visibility, then exact per-pixel resolve and shading.
pub fn render(scene: &Scene, k: &Intrinsics) -> GBuffer {
    let g = Geometry::build(scene);
    let vb = visibility(&g, k);
    let (w, h) = (vb.width, vb.height);
    let n = w * h;
    let mut gb = GBuffer {
        width: w,
        height: h,
        depth_m: vec![0.0; n],
        item: vec![NO_ITEM; n],
        nocs: vec![[0.0; 3]; n],
        handle: vec![false; n],
        color: vec![[0.5; 3]; n],
        albedo_luma: vec![0.0; n],
        specular: vec![0.0; n],
    };
    for v in 0..h {
        let dy = (v as f64 - k.cy) / k.fy;
        for u in 0..w {
            let i = v * w + u;
            let t = vb.tri[i];
            if t == NO_TRI {
                continue;
            }
            let tri = g.tris[t as usize];
            let (a, b, c) = (tri[0] as usize, tri[1] as usize, tri[2] as usize);
            let d = [(u as f64 - k.cx) / k.fx, dy, 1.0];
            // Moller-Trumbore from the camera centre.
            let (p0, p1, p2) = (to64(g.pos[a]), to64(g.pos[b]), to64(g.pos[c]));
            let e1 = sub(p1, p0);
            let e2 = sub(p2, p0);
            let pv = cross(d, e2);
            let det = dot(e1, pv);
            let z_raster = 1.0 / f64::from(vb.inv_z[i]);
            let mut bary = None;
            if det.abs() > 1e-14 {
                let inv = 1.0 / det;
                let tv = [-p0[0], -p0[1], -p0[2]];
                let b1 = dot(tv, pv) * inv;
                let qv = cross(tv, e1);
                let b2 = dot(d, qv) * inv;
                let z = dot(e2, qv) * inv;
                if z > 0.0 && (z / z_raster - 1.0).abs() < 0.02 {
                    bary = Some(([(1.0 - b1 - b2) as f32, b1 as f32, b2 as f32], z));
                }
            }
            let (bw, z) = bary.unwrap_or(([1.0 / 3.0; 3], z_raster));
            gb.depth_m[i] = z as f32;
            let item = g.tri_item[t as usize];
            gb.item[i] = item;
            gb.nocs[i] = interp([g.nocs[a], g.nocs[b], g.nocs[c]], bw);
            gb.handle[i] = g.tri_tag[t as usize] == TAG_HANDLE;
            let bc = [bw[0].clamp(0.0, 1.0), bw[1].clamp(0.0, 1.0), bw[2].clamp(0.0, 1.0)];
            let nn = interp([g.nrm[a], g.nrm[b], g.nrm[c]], bc);
            let len = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt().max(1e-12);
            let nn = [nn[0] / len, nn[1] / len, nn[2] / len];
            let tex = interp([g.tex[a], g.tex[b], g.tex[c]], bw);
            let mat = &g.materials[usize::from(g.tri_mat[t as usize])];
            let dl = (d[0] * d[0] + d[1] * d[1] + 1.0).sqrt();
            let df = [(d[0] / dl) as f32, (d[1] / dl) as f32, (1.0 / dl) as f32];
            let s = scene.lighting.shade(mat, mat.albedo(tex), nn, df);
            gb.color[i] = s.rgb;
            gb.albedo_luma[i] = s.albedo_luma;
            gb.specular[i] = s.specular;
        }
    }
    gb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shared_edges_cover_each_pixel_once() {
        // Two triangles forming a square; count writes per pixel.
        let mut vb = VisBuffer { width: 20, height: 20, inv_z: vec![0.0; 400], tri: vec![NO_TRI; 400] };
        let a = [2.0, 2.0, 1.0];
        let b = [17.0, 3.0, 1.0];
        let c = [16.0, 18.0, 1.0];
        let d = [3.0, 15.0, 1.0];
        vb.raster([a, b, c], 0);
        let first: Vec<bool> = vb.tri.iter().map(|&t| t == 0).collect();
        let mut vb2 = VisBuffer { width: 20, height: 20, inv_z: vec![0.0; 400], tri: vec![NO_TRI; 400] };
        vb2.raster([a, c, d], 1);
        let overlap = first.iter().zip(&vb2.tri).filter(|&(&f, &t)| f && t == 1).count();
        assert_eq!(overlap, 0);
        // Grid-aligned shared edge (pixel centres exactly on it).
        let mut vb3 = VisBuffer { width: 20, height: 20, inv_z: vec![0.0; 400], tri: vec![NO_TRI; 400] };
        vb3.raster([[2.0, 2.0, 1.0], [12.0, 2.0, 1.0], [2.0, 12.0, 1.0]], 0);
        let mut vb4 = VisBuffer { width: 20, height: 20, inv_z: vec![0.0; 400], tri: vec![NO_TRI; 400] };
        vb4.raster([[12.0, 2.0, 1.0], [12.0, 12.0, 1.0], [2.0, 12.0, 1.0]], 1);
        let both = vb3.tri.iter().zip(&vb4.tri).filter(|&(&x, &y)| x == 0 && y == 1).count();
        let either = vb3.tri.iter().zip(&vb4.tri).filter(|&(&x, &y)| x == 0 || y == 1).count();
        assert_eq!(both, 0);
        assert_eq!(either, 100, "a 10x10 pixel square is covered exactly once");
    }
}
