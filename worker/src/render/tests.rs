//! Behaviour of the renderer on whatever adapter the machine has (lavapipe in CI).

use nalgebra::{Point3, Vector3};

use super::*;
use crate::camera::{Camera, decode_depth};
use crate::geometry::{ID_HUMAN, ID_NONE, Part, Shape};

/// A renderer, or None (with a note) on a machine without any wgpu adapter.
fn renderer(cfg: &RenderConfig) -> Option<Renderer> {
    match Renderer::new(cfg) {
        Ok(r) => Some(r),
        Err(RenderError::NoAdapter(b)) => {
            assert!(!adapter_required(), "no wgpu adapter ({b}), but CI or scripts/setup.sh says there must be one");
            eprintln!("skipped: no wgpu adapter ({b})");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

fn cfg(width: u32, height: u32, per_submit: usize) -> RenderConfig {
    RenderConfig { width, height, fov_deg: 90.0, max_views_per_submit: per_submit }
}

/// Owned images of one view.
#[derive(Clone, Debug, PartialEq)]
struct Frame {
    w: usize,
    rgb: Vec<u8>,
    depth: Vec<u16>,
    ids: Vec<u16>,
}

impl Frame {
    fn at(&self, x: usize, y: usize) -> ([u8; 3], u16, u16) {
        let i = y * self.w + x;
        ([self.rgb[3 * i], self.rgb[3 * i + 1], self.rgb[3 * i + 2]], self.depth[i], self.ids[i])
    }
}

fn render(r: &mut Renderer, views: &[View<'_>]) -> Vec<Frame> {
    let (w, h) = (r.config().width as usize, r.config().height as usize);
    let mut frames: Vec<Frame> = views
        .iter()
        .map(|_| Frame { w, rgb: vec![7; w * h * 3], depth: vec![7; w * h], ids: vec![7; w * h] })
        .collect();
    let mut outs: Vec<ViewOut> =
        frames.iter_mut().map(|f| ViewOut { rgb: &mut f.rgb, depth: &mut f.depth, ids: Some(&mut f.ids) }).collect();
    r.render(views, &mut outs).unwrap();
    frames
}

fn red_box(center: [f32; 3], half: f32, id: u16) -> Part {
    Part::new(Shape::Box, Point3::from(center), Vector3::repeat(half), [0.9, 0.05, 0.05]).with_id(id)
}

fn eye(yaw: f32) -> Camera {
    Camera::new(Point3::new(0.0, 1.5, 0.0), yaw)
}

#[test]
fn red_box_straight_ahead_is_red_at_two_metres_with_its_id() {
    let Some(mut r) = renderer(&cfg(224, 224, 4)) else { return };
    // front face at z = 2
    let scene = r.upload_scene(&[red_box([0.0, 1.5, 2.25], 0.25, 7)]);
    let f = &render(&mut r, &[View { scene, camera: eye(0.0), dynamic: &[] }])[0];
    let (rgb, depth, id) = f.at(112, 112);
    assert!(rgb[0] > 100 && rgb[0] as u32 > 2 * rgb[1] as u32 && rgb[0] as u32 > 2 * rgb[2] as u32, "{rgb:?}");
    assert!((decode_depth(depth) - 2.0).abs() < 0.02, "depth {}", decode_depth(depth));
    assert_eq!(id, 7);
    // the front face spans columns 112 ± 14 (half width 0.25 at 2 m, 90° fov)
    assert_eq!(f.at(112 + 12, 112).2, 7);
    assert_eq!(f.at(112 - 12, 112).2, 7);
    assert_eq!(f.at(112 + 16, 112).2, ID_NONE);
    assert_eq!(count_id(&f.ids, 7), f.ids.iter().filter(|&&v| v == 7).count() as u32);
}

#[test]
fn plus_x_is_on_the_right_and_yaw_90_looks_along_plus_x() {
    let Some(mut r) = renderer(&cfg(224, 224, 4)) else { return };
    let right = r.upload_scene(&[red_box([1.0, 1.5, 3.0], 0.3, 9)]);
    let ahead_x = r.upload_scene(&[red_box([3.0, 1.5, 0.0], 0.3, 9)]);
    let frames = render(
        &mut r,
        &[
            View { scene: right, camera: eye(0.0), dynamic: &[] },
            View { scene: ahead_x, camera: eye(90.0), dynamic: &[] },
        ],
    );
    let f = &frames[0];
    let mut cols = (0..224 * 224).filter(|i| f.ids[*i] == 9).map(|i| i % 224);
    assert!(count_id(&f.ids, 9) > 100);
    assert!(cols.all(|x| x >= 112), "the box at +x must be in the right half");
    let f = &frames[1];
    assert_eq!(f.at(112, 112).2, 9);
    assert!((decode_depth(f.at(112, 112).1) - 2.7).abs() < 0.02);
}

#[test]
fn depth_is_along_the_view_axis_not_the_ray() {
    let Some(mut r) = renderer(&cfg(224, 224, 1)) else { return };
    // a wall filling the view, 3 m ahead
    let wall = Part::new(Shape::Box, Point3::new(0.0, 1.5, 3.5), Vector3::new(10.0, 10.0, 0.5), [0.5; 3]);
    let scene = r.upload_scene(&[wall]);
    let f = &render(&mut r, &[View { scene, camera: eye(0.0), dynamic: &[] }])[0];
    for (x, y) in [(0, 0), (223, 0), (0, 223), (223, 223), (112, 112), (50, 170)] {
        let d = decode_depth(f.at(x, y).1);
        assert!((d - 3.0).abs() < 0.01, "pixel ({x}, {y}) at {d} m");
    }
}

#[test]
fn empty_view_is_far_and_has_no_ids() {
    let Some(mut r) = renderer(&cfg(64, 64, 2)) else { return };
    let scene = r.upload_scene(&[]);
    let far = r.upload_scene(&[red_box([0.0, 1.5, 14.0], 1.0, 5)]);
    let frames = render(
        &mut r,
        &[View { scene, camera: eye(0.0), dynamic: &[] }, View { scene: far, camera: eye(0.0), dynamic: &[] }],
    );
    let f = &frames[0];
    assert!(f.depth.iter().all(|&d| d == 65535));
    assert!(f.ids.iter().all(|&i| i == ID_NONE));
    assert!(f.rgb.iter().all(|&c| c == 0));
    // beyond 10 m: visible, but the depth saturates
    let f = &frames[1];
    assert_eq!(f.at(32, 32).2, 5);
    assert_eq!(f.at(32, 32).1, 65535);
}

fn room_views(parts: &[Part], n: usize) -> Vec<Camera> {
    bench::spread_cameras(parts, n)
}

#[test]
fn a_batch_equals_the_same_views_one_by_one_and_repeats_exactly() {
    let Some(mut r) = renderer(&cfg(224, 224, 16)) else { return };
    let parts = benchmark_room().parts();
    let scene = r.upload_scene(&parts);
    let figure = figure_parts(Point3::new(0.3, 0.0, 0.2), 30.0, true);
    let cams = room_views(&parts, 16);
    let views: Vec<View> = cams
        .iter()
        .enumerate()
        .map(|(i, &camera)| View { scene, camera, dynamic: if i % 2 == 0 { &figure } else { &[] } })
        .collect();
    let batch = render(&mut r, &views);
    let single: Vec<Frame> = views.iter().map(|v| render(&mut r, std::slice::from_ref(v)).remove(0)).collect();
    for (i, (a, b)) in batch.iter().zip(&single).enumerate() {
        assert!(a == b, "view {i} differs between the batch and a single render");
    }
    let again = render(&mut r, &views);
    assert!(again == batch, "same input, different bytes");
    r.set_frustum_culling(false);
    assert!(render(&mut r, &views) == batch, "frustum culling changed the image");
    r.set_frustum_culling(true);
    // the views are not trivially alike: they see different things
    assert!(batch[0] != batch[1]);
    assert!(batch.iter().all(|f| f.ids.iter().any(|&i| i >= crate::geometry::ID_FIRST_OBJECT)));
    // more views than one submit holds are chunked with the same result
    let mut small = renderer(&cfg(224, 224, 3)).unwrap();
    let scene = small.upload_scene(&parts);
    let views: Vec<View> = views.iter().map(|v| View { scene, ..*v }).collect();
    assert!(render(&mut small, &views) == batch);
}

#[test]
fn culling_never_changes_a_pixel_of_small_images() {
    // at 32×32 many parts fall between pixel centres and are skipped
    let Some(mut r) = renderer(&cfg(32, 32, 8)) else { return };
    let parts = benchmark_room().parts();
    let scene = r.upload_scene(&parts);
    let figure = figure_parts(Point3::new(0.3, 0.0, 0.2), 30.0, true);
    let views: Vec<View> = room_views(&parts, 8)
        .iter()
        .enumerate()
        .map(|(i, &camera)| View { scene, camera, dynamic: if i % 2 == 0 { &figure } else { &[] } })
        .collect();
    let culled = render(&mut r, &views);
    r.set_frustum_culling(false);
    assert!(render(&mut r, &views) == culled, "culling changed the image");
}

#[test]
fn lanes_split_a_chunk_without_changing_a_byte() {
    let Some(mut one) = renderer(&cfg(64, 64, 8)) else { return };
    let parts = benchmark_room().parts();
    let figure = figure_parts(Point3::new(0.3, 0.0, 0.2), 30.0, true);
    let cams = room_views(&parts, 11);
    let frames = |r: &mut Renderer| {
        let scene = r.upload_scene(&parts);
        let views: Vec<View> = cams
            .iter()
            .enumerate()
            .map(|(i, &camera)| View { scene, camera, dynamic: if i % 3 == 0 { &figure } else { &[] } })
            .collect();
        render(r, &views)
    };
    let expected = frames(&mut one);
    for lanes in [2, 3] {
        let mut r = Renderer::with_lanes(&cfg(64, 64, 8), lanes).unwrap();
        assert_eq!(r.lanes(), lanes);
        assert!(frames(&mut r) == expected, "{lanes} lanes");
    }
    assert_eq!(Renderer::with_lanes(&cfg(64, 64, 2), 4).unwrap().lanes(), 2);
    assert!(matches!(Renderer::with_lanes(&cfg(64, 64, 2), 0), Err(RenderError::BadLanes(_))));
}

#[test]
fn a_dynamic_part_appears_and_disappears_between_frames() {
    let Some(mut r) = renderer(&cfg(128, 128, 4)) else { return };
    let parts = benchmark_room().parts();
    let scene = r.upload_scene(&parts);
    let figure = figure_parts(Point3::new(0.0, 0.0, 1.5), 180.0, false);
    let camera = Camera::new(Point3::new(0.0, 1.5, -0.5), 0.0);
    let with = &render(&mut r, &[View { scene, camera, dynamic: &figure }])[0];
    let without = &render(&mut r, &[View { scene, camera, dynamic: &[] }])[0];
    let again = &render(&mut r, &[View { scene, camera, dynamic: &figure }])[0];
    assert!(count_id(&with.ids, ID_HUMAN) > 200, "{}", count_id(&with.ids, ID_HUMAN));
    assert_eq!(count_id(&without.ids, ID_HUMAN), 0);
    assert!(with == again);
    // the person hides what is behind them: something else shows there without them
    let i = with.ids.iter().position(|&v| v == ID_HUMAN).unwrap();
    assert_ne!(without.ids[i], ID_HUMAN);
    assert!(without.depth[i] > with.depth[i]);
}

#[test]
fn non_square_images_keep_the_vertical_fov_and_orientation() {
    let (w, h) = (160u32, 96u32);
    let Some(mut r) = renderer(&cfg(w, h, 2)) else { return };
    let scene = r.upload_scene(&[red_box([0.0, 1.5, 2.25], 0.25, 4), red_box([1.6, 1.5, 2.25], 0.25, 5)]);
    let f = &render(&mut r, &[View { scene, camera: eye(0.0), dynamic: &[] }])[0];
    assert_eq!(f.rgb.len(), (w * h * 3) as usize);
    assert_eq!(f.at(80, 48).2, 4);
    // the second box: projected with the same math as the shader
    let c = r.config().clone();
    let (px, py, d) = project(&eye(0.0), &c, Point3::new(1.6, 1.5, 2.0)).unwrap();
    assert!(px > 110.0, "{px}");
    let (_, depth, id) = f.at(px as usize, py as usize);
    assert_eq!(id, 5);
    assert!((decode_depth(depth) - d).abs() < 0.02);
    // the vertical field is 90°: a point 1 m up at 2 m lies a quarter of the height up
    let (_, py, _) = project(&eye(0.0), &c, Point3::new(0.0, 2.5, 2.0)).unwrap();
    assert!((py - 24.0).abs() < 1e-3);
}

#[test]
fn projection_agrees_with_the_rendered_ids() {
    let Some(mut r) = renderer(&cfg(224, 224, 4)) else { return };
    let scene_desc = benchmark_room();
    let parts = scene_desc.parts();
    let scene = r.upload_scene(&parts);
    let cams = room_views(&parts, 4);
    let views: Vec<View> = cams.iter().map(|&camera| View { scene, camera, dynamic: &[] }).collect();
    let frames = render(&mut r, &views);
    let mut checked = 0;
    for (cam, f) in cams.iter().zip(&frames) {
        for p in parts.iter().filter(|p| p.id >= crate::geometry::ID_FIRST_OBJECT) {
            let Some((px, py, d)) = project(cam, r.config(), p.center) else { continue };
            let (_, depth, id) = f.at(px as usize, py as usize);
            // where the part's centre is the visible surface, the pixel shows that part
            if id == p.id && (decode_depth(depth) - d).abs() < 0.5 {
                checked += 1;
            }
            // nothing can be seen farther than the centre of an unoccluded part in front of it
            if id == p.id {
                assert!(decode_depth(depth) <= d + 0.5 * p.half_extents.norm() + 0.02);
            }
        }
    }
    assert!(checked > 5, "only {checked} parts seen where projected");
}

#[test]
fn depth_alone_and_bad_outputs() {
    let Some(mut r) = renderer(&cfg(32, 32, 2)) else { return };
    let scene = r.upload_scene(&[red_box([0.0, 1.5, 2.25], 0.25, 7)]);
    let view = View { scene, camera: eye(0.0), dynamic: &[] };
    let (mut rgb, mut depth) = (vec![0u8; 32 * 32 * 3], vec![0u16; 32 * 32]);
    r.render(&[view], &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: None }]).unwrap();
    assert!((decode_depth(depth[16 * 32 + 16]) - 2.0).abs() < 0.02);

    let mut short = vec![0u8; 10];
    let err = r.render(&[view], &mut [ViewOut { rgb: &mut short, depth: &mut depth, ids: None }]).unwrap_err();
    assert!(matches!(err, RenderError::OutputSize { field: "rgb", .. }), "{err}");
    let err = r.render(&[view, view], &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: None }]).unwrap_err();
    assert!(matches!(err, RenderError::OutputCount { .. }), "{err}");
    r.release_scene(scene);
    let err = r.render(&[view], &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: None }]).unwrap_err();
    assert!(matches!(err, RenderError::UnknownScene { index: 0 }), "{err}");
    // a slot reused by a new scene does not revive the old handle
    let other = r.upload_scene(&[red_box([0.0, 1.5, 3.0], 0.25, 8)]);
    assert_ne!(other, scene);
    assert!(r.render(&[view], &mut [ViewOut { rgb: &mut rgb, depth: &mut depth, ids: None }]).is_err());
}

#[test]
fn bench_views_measures_something() {
    let Some(mut r) = renderer(&cfg(64, 64, 4)) else { return };
    let parts = benchmark_room().parts();
    let v = bench_views(&mut r, &parts, 4, 0.0).unwrap();
    assert!(v.is_finite() && v > 0.0);
}

#[test]
fn adapter_is_described() {
    let Some(r) = renderer(&cfg(16, 16, 1)) else { return };
    let s = r.adapter_info();
    assert!(s.contains("Vulkan") || s.contains("Gl"), "{s}");
}

#[test]
fn a_renderer_can_move_to_another_thread() {
    fn send<T: Send>() {}
    send::<Renderer>();
}

/// Frames kept on the device: every view lands in its slot byte for byte as the read-back path
/// gives it, in chunks and out of order, and the target counts equal `count_id` of the
/// read-back ids.
#[test]
fn exported_frames_equal_the_read_back_ones() {
    let Some(mut r) = renderer(&cfg(40, 24, 2)) else { return };
    let parts = benchmark_room().parts();
    let scene = r.upload_scene(&parts);
    let cameras = spread_cameras(&parts, 3);
    let c = cameras[0].position;
    let figure = figure_parts(Point3::new(c.x + 0.4, 0.0, c.z + 1.2), 200.0, true);
    let views: Vec<View> = cameras.iter().map(|&camera| View { scene, camera, dynamic: &figure }).collect();
    let expected = render(&mut r, &views);
    let exported = match r.export_frames(4) {
        Ok(e) => e,
        Err(e) => {
            assert!(!adapter_required(), "{e}, but CI or scripts/setup.sh installs lavapipe, which exports");
            eprintln!("skipped: {e}");
            return;
        }
    };
    let layout = exported.layout();
    assert_eq!((layout.slots, layout.row_bytes), (4, 256));
    assert!(layout.size >= 2 * layout.info_offset);
    let fd = exported.fd().try_clone_to_owned().unwrap();
    // the person's id and one that shows in the first view, and one that shows nowhere
    let shown = *expected[1].ids.iter().find(|&&i| i != ID_NONE && i != ID_HUMAN).unwrap_or(&ID_NONE);
    let targets = [ID_HUMAN, shown, 60_000];
    let wanted: Vec<u32> = expected.iter().zip(targets).map(|(f, t)| count_id(&f.ids, t)).collect();
    assert!(wanted[0] > 0 && wanted[1] > 0 && wanted[2] == 0, "{wanted:?}");
    if r.is_cpu() {
        // lavapipe's exported memory is a memfd; a GPU's fd has no size of its own
        let stat = nix::sys::stat::fstat(&fd).unwrap();
        assert!(stat.st_size as u64 >= layout.size, "the exported fd holds {} bytes", stat.st_size);
    }
    // out of order, then in runs of consecutive slots (one copy each) across chunks of two
    for slots in [[3, 0, 2], [1, 2, 3]] {
        assert_eq!(r.render_exported(&views, &slots, &targets).unwrap(), wanted, "slots {slots:?}");
        // the memory as the device holds it (`learner::device_frames` imports the fd itself)
        let bytes = r.read_exported().unwrap();
        assert_eq!(bytes.len() as u64, layout.size);
        let (w, h, row) = (40, 24, layout.row_bytes as usize);
        for (f, &slot) in expected.iter().zip(&slots) {
            let colour = &bytes[slot as usize * layout.layer_bytes as usize..];
            let info = &bytes[(layout.info_offset + slot as u64 * layout.layer_bytes) as usize..];
            for y in 0..h {
                for x in 0..w {
                    let (rgb, depth, id) = f.at(x, y);
                    let p = y * row + x * 4;
                    assert_eq!(&colour[p..p + 3], &rgb, "slot {slot} ({x}, {y}) of {slots:?}");
                    let v = u32::from_le_bytes(info[p..p + 4].try_into().unwrap());
                    assert_eq!(((v >> 16) as u16, v as u16), (depth, id), "slot {slot} ({x}, {y}) of {slots:?}");
                }
            }
        }
    }
    // another layout is refused; slots beyond the memory too
    assert!(matches!(r.export_frames(5), Err(RenderError::Export(_))));
    let err = r.render_exported(&views[..1], &[4], &[ID_HUMAN]).unwrap_err();
    assert!(err.to_string().contains("slot 4 of 4"), "{err}");
}
