//! Scene sampling: NOCS objects standing on a table without interpenetration,
//! distractors, a textured table inside a room, lights and a camera above the
//! table looking at the object cluster.

use super::mesh::TriMesh;
use super::shading::{Light, Lighting, Material, Pattern, hsv, random_color};
use super::shapes::{ObjectModel, generate_object};
use crate::category::Category;
use crate::geometry::{Mat3, Pose, Vec3, rotation_axis_angle, rotation_y};
use crate::rng::Rng;

/// Camera elevation above the table plane, degrees.
pub const CAMERA_ELEVATION_DEG: (f64, f64) = (15.0, 75.0);
/// Camera distance to the look-at point, metres.
pub const CAMERA_DISTANCE_M: (f64, f64) = (0.45, 1.2);
/// Standard deviation of the camera roll, degrees (clamped to 3 sigma).
pub const CAMERA_ROLL_SIGMA_DEG: f64 = 3.0;
/// Standard deviation of the look-at jitter on the table, metres.
pub const LOOK_AT_JITTER_M: f64 = 0.03;
/// Gap kept between footprint circles, metres.
pub const FOOTPRINT_GAP_M: f64 = 0.005;
/// Height of the table top above the floor, metres.
pub const TABLE_HEIGHT_M: f64 = 0.75;

/// A NOCS object placed in the scene.
#[derive(Clone, Debug)]
pub struct PlacedObject {
    /// Category.
    pub category: Category,
    /// Tight metric box size (x, y, z).
    pub size_m: [f64; 3],
    /// Object (metric NOCS frame) to camera.
    pub camera_from_object: Pose,
}

/// Something to render: a mesh in its local frame with materials.
#[derive(Clone, Debug)]
pub struct Item {
    /// Mesh in local coordinates.
    pub mesh: TriMesh,
    /// Camera point = `rotation * (scale * local) + translation`.
    pub camera_from_local: Pose,
    /// Uniform scale from local units to metres.
    pub scale: f64,
    /// Materials indexed by the mesh's material slots.
    pub materials: Vec<Material>,
    /// Texture coordinate = local / tex_scale + tex_offset.
    pub tex_scale: f64,
    /// See `tex_scale`.
    pub tex_offset: Vec3,
    /// Index into [`Scene::objects`] for NOCS objects (local = NOCS frame).
    pub object: Option<usize>,
    /// Whether this is a distractor (a box, sphere, cylinder or torus: no NOCS object).
    pub distractor: bool,
}

/// A sampled scene, already expressed in the camera frame.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The NOCS objects, in sampling order.
    pub objects: Vec<PlacedObject>,
    /// Everything to render (objects first, in the same order, then the rest).
    pub items: Vec<Item>,
    /// Lights in the camera frame.
    pub lighting: Lighting,
    /// World (table top y = 0, y up) to camera.
    pub camera_from_world: Pose,
}

/// What the sampler needs from the configuration.
#[derive(Clone, Copy, Debug)]
pub struct SceneParams {
    /// Fewest NOCS objects.
    pub min_objects: usize,
    /// Most NOCS objects.
    pub max_objects: usize,
    /// Most distractors.
    pub max_distractors: usize,
}

struct Footprint {
    x: f64,
    z: f64,
    r: f64,
}

fn place(rng: &mut Rng, placed: &[Footprint], r: f64, cluster_r: f64) -> Option<(f64, f64)> {
    let mut radius = cluster_r;
    for attempt in 0..120 {
        if attempt % 30 == 29 {
            radius *= 1.15;
        }
        let a = rng.range(0.0, std::f64::consts::TAU);
        let d = radius * rng.uniform().sqrt();
        let (x, z) = (d * a.cos(), d * a.sin());
        if placed.iter().all(|f| ((f.x - x).powi(2) + (f.z - z).powi(2)).sqrt() >= f.r + r + FOOTPRINT_GAP_M) {
            return Some((x, z));
        }
    }
    None
}

fn distractor(rng: &mut Rng) -> (TriMesh, f64, f64) {
    // (mesh with its bottom at y = 0, footprint radius, unused)
    match rng.below(4) {
        0 => {
            let (sx, sy, sz) = (rng.range(0.03, 0.16), rng.range(0.02, 0.16), rng.range(0.03, 0.16));
            let m = TriMesh::cuboid(Vec3::new(-sx / 2.0, 0.0, -sz / 2.0), Vec3::new(sx / 2.0, sy, sz / 2.0), [0; 6], 0);
            (m, 0.5 * (sx * sx + sz * sz).sqrt(), sy)
        }
        1 => {
            let r = rng.range(0.02, 0.07);
            let mut m = TriMesh::sphere(r, 32, 0);
            m.transform(&Mat3::identity(), &Vec3::new(0.0, r, 0.0));
            (m, r, 2.0 * r)
        }
        2 => {
            let (r, h) = (rng.range(0.02, 0.07), rng.range(0.02, 0.2));
            (TriMesh::cylinder(r, 0.0, h, 32, 0, 0), r, h)
        }
        _ => {
            let (big, small) = (rng.range(0.03, 0.07), rng.range(0.008, 0.025));
            let mut m = TriMesh::torus(big, small, 32, 12, 0);
            m.transform(&Mat3::identity(), &Vec3::new(0.0, small, 0.0));
            (m, big + small, 2.0 * small)
        }
    }
}

fn look_at(eye: Vec3, target: Vec3, roll_rad: f64) -> Pose {
    let f = (target - eye).normalize();
    let right = f.cross(&Vec3::y()).normalize();
    let down = f.cross(&right);
    let roll = rotation_axis_angle(&f, roll_rad);
    let world_from_camera_rot = roll * Mat3::from_columns(&[right, down, f]);
    Pose::new(world_from_camera_rot, eye).inverse()
}

/// Samples a scene. Deterministic in `rng`.
pub fn sample_scene(params: &SceneParams, rng: &mut Rng) -> Scene {
    let n_obj = rng.int_incl(params.min_objects, params.max_objects.max(params.min_objects));
    let n_dis = rng.int_incl(0, params.max_distractors);
    let cluster_r = 0.06 + 0.045 * (n_obj + n_dis) as f64;
    let mut footprints: Vec<Footprint> = Vec::new();
    let mut models: Vec<(ObjectModel, Pose)> = Vec::new();
    for _ in 0..n_obj {
        let category = Category::ALL[rng.below(Category::ALL.len())];
        let model = generate_object(category, rng);
        let s = model.size_m();
        let r = 0.5 * (s[0] * s[0] + s[2] * s[2]).sqrt();
        let yaw = rng.range(0.0, std::f64::consts::TAU);
        if let Some((x, z)) = place(rng, &footprints, r, cluster_r) {
            footprints.push(Footprint { x, z, r });
            models.push((model, Pose::new(rotation_y(yaw), Vec3::new(x, s[1] / 2.0, z))));
        }
    }
    let mut distractors = Vec::new();
    for _ in 0..n_dis {
        let (mesh, r, _) = distractor(rng);
        let yaw = rng.range(0.0, std::f64::consts::TAU);
        let mat = Material::random(rng, 0.5);
        if let Some((x, z)) = place(rng, &footprints, r, cluster_r) {
            footprints.push(Footprint { x, z, r });
            distractors.push((mesh, Pose::new(rotation_y(yaw), Vec3::new(x, 0.0, z)), mat));
        }
    }

    // Camera.
    let (mut cx, mut cz) = (0.0, 0.0);
    for (_, p) in &models {
        cx += p.translation_m.x;
        cz += p.translation_m.z;
    }
    let n = models.len().max(1) as f64;
    let target = Vec3::new(
        cx / n + LOOK_AT_JITTER_M * rng.normal(),
        rng.range(0.0, 0.08),
        cz / n + LOOK_AT_JITTER_M * rng.normal(),
    );
    let el = rng.range(CAMERA_ELEVATION_DEG.0, CAMERA_ELEVATION_DEG.1).to_radians();
    let az = rng.range(0.0, std::f64::consts::TAU);
    let dist = rng.range(CAMERA_DISTANCE_M.0, CAMERA_DISTANCE_M.1);
    let roll = (CAMERA_ROLL_SIGMA_DEG * rng.normal()).clamp(-3.0 * CAMERA_ROLL_SIGMA_DEG, 3.0 * CAMERA_ROLL_SIGMA_DEG);
    let eye = target + dist * Vec3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
    let camera_from_world = look_at(eye, target, roll.to_radians());

    let mut objects = Vec::new();
    let mut items = Vec::new();
    for (k, (model, world_from_object)) in models.into_iter().enumerate() {
        let camera_from_object = camera_from_world.compose(&world_from_object);
        objects.push(PlacedObject { category: model.category, size_m: model.size_m(), camera_from_object });
        items.push(Item {
            mesh: model.mesh,
            camera_from_local: camera_from_object,
            scale: model.scale,
            materials: model.materials,
            tex_scale: model.tex_scale,
            tex_offset: model.tex_offset,
            object: Some(k),
            distractor: false,
        });
    }
    for (mesh, world_from_local, mat) in distractors {
        items.push(Item {
            mesh,
            camera_from_local: camera_from_world.compose(&world_from_local),
            scale: 1.0,
            materials: vec![mat],
            tex_scale: 1.0,
            tex_offset: Vec3::zeros(),
            object: None,
            distractor: true,
        });
    }

    // Table (top at y = 0) and room.
    let (tx, tz) = (rng.range(0.7, 1.1), rng.range(0.7, 1.1));
    let (ox, oz) = (rng.range(-0.1, 0.1), rng.range(-0.1, 0.1));
    let table = TriMesh::cuboid(
        Vec3::new(ox - tx, -TABLE_HEIGHT_M, oz - tz),
        Vec3::new(ox + tx, 0.0, oz + tz),
        [0, 0, 0, 1, 0, 0],
        0,
    );
    let top = match rng.below(4) {
        0 => {
            let (h, v) = (rng.range(0.04, 0.11) as f32, rng.range(0.35, 0.75) as f32);
            let base = hsv(h, rng.range(0.45, 0.8) as f32, v);
            let alt = hsv(h, 0.8, v * 0.6);
            Material {
                base,
                alt,
                pattern: Pattern::Wood { freq: rng.range(8.0, 25.0) as f32 },
                specular: 0.1,
                shininess: 16.0,
            }
        }
        1 => Material { pattern: Pattern::Checker { freq: rng.range(3.0, 12.0) as f32 }, ..Material::random(rng, 0.0) },
        2 => Material { pattern: Pattern::Noise { freq: rng.range(5.0, 40.0) as f32 }, ..Material::random(rng, 0.0) },
        _ => Material {
            pattern: Pattern::Stripes { axis: rng.pick(&[0u8, 2]), freq: rng.range(2.0, 10.0) as f32 },
            ..Material::random(rng, 0.0)
        },
    };
    let top = Material { specular: rng.range(0.0, 0.25) as f32, ..top };
    let edge = Material::solid(random_color(rng), 0.1);
    let (wx, wz) = (rng.range(1.6, 2.6), rng.range(1.6, 2.6));
    let room = TriMesh::cuboid(Vec3::new(-wx, -TABLE_HEIGHT_M, -wz), Vec3::new(wx, 2.4, wz), [0, 0, 1, 2, 0, 0], 0);
    let wall = Material { pattern: Pattern::Noise { freq: rng.range(1.0, 6.0) as f32 }, ..Material::random(rng, 0.0) };
    let wall = Material { specular: 0.0, alt: scale_color(wall.base, 0.85), ..wall };
    let floor = Material::random(rng, 0.7);
    let ceiling = Material::solid([0.85, 0.85, 0.85], 0.0);
    for (mesh, materials) in [(table, vec![edge, top]), (room, vec![wall, floor, ceiling])] {
        items.push(Item {
            mesh,
            camera_from_local: camera_from_world,
            scale: 1.0,
            materials,
            tex_scale: 1.0,
            tex_offset: Vec3::zeros(),
            object: None,
            distractor: false,
        });
    }

    // Lights: ambient plus one or two directional lights from above.
    let ambient = rng.range(0.25, 0.5) as f32;
    let warm = rng.range(-0.05, 0.05) as f32;
    let mut lights = Vec::new();
    let n_lights = 1 + rng.below(2);
    for i in 0..n_lights {
        let el = rng.range(30.0, 85.0f64).to_radians();
        let az = rng.range(0.0, std::f64::consts::TAU);
        let dir_world = Vec3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
        let d = camera_from_world.rotation * dir_world;
        let k = if i == 0 { rng.range(0.5, 0.85) } else { rng.range(0.1, 0.35) } as f32;
        lights
            .push(Light { dir: [d.x as f32, d.y as f32, d.z as f32], color: [k * (1.0 + warm), k, k * (1.0 - warm)] });
    }
    let lighting = Lighting { ambient: [ambient; 3], lights };
    Scene { objects, items, lighting, camera_from_world }
}

fn scale_color(c: [f32; 3], k: f32) -> [f32; 3] {
    [c[0] * k, c[1] * k, c[2] * k]
}
