//! Bad input gets a clear error (never a panic or a silent wrong answer):
//! one test per case of the mesh, observation, hypothesis and GPU inputs.

use std::path::{Path, PathBuf};

use glam::DVec3;
use plausible::gpu::{Context, GpuOptions};
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{read_camera, read_depth_png, read_mask_png, BopCamera};
use plausible::pose::{read_poses, PoseUnits};
use plausible::Error;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn err_text<T: std::fmt::Debug>(r: Result<T, Error>) -> String {
    r.expect_err("expected an error").to_string()
}

const TRI: &str = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 3\n";

#[test]
fn mesh_missing_file() {
    let e = err_text(Mesh::load("/nonexistent/duck.obj", MeshUnits::Auto));
    assert!(e.contains("not found") && e.contains("duck.obj"), "{e}");
}

#[test]
fn mesh_unsupported_extension() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "model.fbx", "whatever");
    let e = err_text(Mesh::load(&p, MeshUnits::Auto));
    assert!(e.contains("unsupported mesh format 'fbx'"), "{e}");
}

#[test]
fn mesh_without_triangles() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "points.obj", "v 0 0 0\nv 1 0 0\n");
    let e = err_text(Mesh::load(&p, MeshUnits::Auto));
    assert!(e.contains("no triangles"), "{e}");
    let p = write(d.path(), "empty.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n");
    assert!(err_text(Mesh::load(&p, MeshUnits::Auto)).contains("no triangles"));
}

#[test]
fn mesh_nan_vertex() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "nan.obj", "v 0 0 0\nv nan 0 0\nv 0 0.1 0\nf 1 2 3\n");
    let e = err_text(Mesh::load(&p, MeshUnits::Auto));
    assert!(e.contains("vertex 1 is not finite"), "{e}");
    let p = write(d.path(), "inf.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\ninf 0 0\n0 1 0\n3 0 1 2\n");
    assert!(err_text(Mesh::load(&p, MeshUnits::Auto)).contains("not finite"));
}

#[test]
fn mesh_index_out_of_range() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "bad.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n");
    let e = err_text(Mesh::load(&p, MeshUnits::Auto));
    assert!(e.contains("face 0 refers to vertex 7") && e.contains("only 3 vertices"), "{e}");
    let p = write(d.path(), "bad.obj", "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 9\n");
    assert!(Mesh::load(&p, MeshUnits::Auto).is_err());
}

#[test]
fn mesh_truncated_binary_ply_and_stl() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("t.ply");
    std::fs::write(&p, b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00").unwrap();
    assert!(err_text(Mesh::load(&p, MeshUnits::Auto)).contains("malformed"));
    let p = d.path().join("t.stl");
    std::fs::write(&p, [0u8; 90]).unwrap();
    assert!(err_text(Mesh::load(&p, MeshUnits::Auto)).contains("malformed"));
}

#[test]
fn mesh_degenerate_faces_and_open_boundary_are_warnings() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "open.obj", &format!("{TRI}v 0.2 0.2 0.2\nf 1 1 4\n"));
    let (mesh, report) = Mesh::load(&p, MeshUnits::Auto).unwrap();
    assert_eq!(mesh.triangles.len(), 1);
    assert_eq!(report.degenerate_faces, 1);
    assert_eq!(report.boundary_edges, 3);
    let text = report.warnings.join("\n");
    assert!(text.contains("degenerate") && text.contains("open"), "{text}");
}

#[test]
fn mesh_units_auto_detects_millimetres() {
    // A BOP-style model in millimetres: 100 mm cube.
    let d = tempfile::tempdir().unwrap();
    let mut text = String::new();
    let c = plausible::shapes::cuboid(DVec3::splat(50.0));
    for v in &c.vertices {
        text += &format!("v {} {} {}\n", v.x, v.y, v.z);
    }
    for t in &c.triangles {
        text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    let p = write(d.path(), "cube_mm.obj", &text);
    let (mesh, report) = Mesh::load(&p, MeshUnits::Auto).unwrap();
    assert!((mesh.diagonal() - 0.1 * 3f64.sqrt()).abs() < 1e-9);
    assert!(report.warnings.iter().any(|w| w.contains("millimetres")));
    let (mm, _) = Mesh::load(&p, MeshUnits::Millimetres).unwrap();
    assert!((mm.diagonal() - mesh.diagonal()).abs() < 1e-12);
    // Stated units are obeyed, but an implausible size is said.
    let (m, r) = Mesh::load(&p, MeshUnits::Metres).unwrap();
    assert!(m.diagonal() > 100.0);
    assert!(r.warnings.iter().any(|w| w.contains("real size")), "{:?}", r.warnings);
}

#[test]
fn mesh_formats_agree() {
    // The same tetrahedron as OBJ, ASCII PLY, binary STL and glTF.
    let d = tempfile::tempdir().unwrap();
    let v = [[0.0f32, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]];
    let f = [[0u32, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let mut obj = String::new();
    let mut ply = String::from("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n");
    for p in v {
        obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
        ply += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    for t in f {
        obj += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
        ply += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    let mut stl = vec![0u8; 80];
    stl.extend(4u32.to_le_bytes());
    for t in f {
        stl.extend([0u8; 12]);
        for i in t {
            for c in v[i as usize] {
                stl.extend(c.to_le_bytes());
            }
        }
        stl.extend([0u8; 2]);
    }
    // Minimal glTF with an embedded base64 buffer.
    let mut bin = Vec::new();
    for p in v {
        for c in p {
            bin.extend(c.to_le_bytes());
        }
    }
    for t in f {
        for i in t {
            bin.extend((i as u16).to_le_bytes());
        }
    }
    let b64 = base64_encode(&bin);
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{b64}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":24}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[0.1,0.1,0.1]}},
                     {{"bufferView":1,"componentType":5123,"count":12,"type":"SCALAR"}}]}}"#,
        bin.len()
    );
    let paths = [
        write(d.path(), "t.obj", &obj),
        write(d.path(), "t.ply", &ply),
        {
            let p = d.path().join("t.stl");
            std::fs::write(&p, &stl).unwrap();
            p
        },
        write(d.path(), "t.gltf", &gltf),
    ];
    for p in &paths {
        let (m, report) = Mesh::load(p, MeshUnits::Metres).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert_eq!(m.triangles.len(), 4, "{}", p.display());
        // Three right triangles of 0.005 m² and one equilateral face of side 0.1·√2.
        let area = 3.0 * 0.005 + 3f64.sqrt() / 4.0 * 0.02;
        assert!((m.area() - area).abs() < 1e-6, "{}: area {}", p.display(), m.area());
        assert_eq!(report.boundary_edges, 0, "{}", p.display());
    }
}

#[test]
fn gltfpack_quantized_glb_matches_its_source_obj() {
    // gltfpack stores positions as 16-bit integers (KHR_mesh_quantization)
    // and puts the scale back in the node; the mesh read must be the OBJ's
    // within the quantization step (the file's 1.65 units over 14 bits, 1e-4).
    let assets = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/");
    let (obj, _) = Mesh::load(format!("{assets}duck.obj"), MeshUnits::Metres).unwrap();
    let (glb, _) = Mesh::load(format!("{assets}duck_gltfpack.glb"), MeshUnits::Metres).unwrap();
    assert_eq!(glb.triangles.len(), obj.triangles.len());
    let ((a0, a1), (b0, b1)) = (obj.bounds(), glb.bounds());
    let step = 1.0e-4;
    assert!(a0.distance(b0) < step && a1.distance(b1) < step, "bounds {a0} {a1} vs {b0} {b1}");
    assert!((glb.area() / obj.area() - 1.0).abs() < 1e-3, "area {} vs {}", glb.area(), obj.area());
}

fn base64_encode(data: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in data.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn camera(dir: &Path) -> PathBuf {
    write(dir, "camera.json", r#"{"cam_K": [572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 1], "depth_scale": 0.1}"#)
}

#[test]
fn camera_errors() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "c1.json", r#"{"cam_K": [1, 2, 3], "depth_scale": 1}"#);
    // K is checked as the camera is read (its errors name the camera file).
    let e = err_text(read_camera(&p, None));
    assert!(e.contains("c1.json") && e.contains("expected 9 numbers"), "{e}");
    let p = write(d.path(), "c2.json", r#"{"1": {"cam_K": [1,0,0,0,1,0,0,0,1], "depth_scale": 1}, "2": {"cam_K": [1,0,0,0,1,0,0,0,1], "depth_scale": 1}}"#);
    assert!(err_text(read_camera(&p, None)).contains("pick one by its id"));
    assert!(read_camera(&p, Some("2")).is_ok());
    assert!(err_text(read_camera(&p, Some("3"))).contains("no frame '3'"));
    // Both say the frame picked is at fault (the CLI names --frame).
    assert_eq!(read_camera(&p, Some("3")).unwrap_err().input(), Some(plausible::Input::Selection));
    assert_eq!(read_camera(&p, None).unwrap_err().input(), Some(plausible::Input::Selection));
    // A frame id that a one-frame scene_camera.json does not hold is an error, not ignored.
    let p = write(d.path(), "c4.json", r#"{"3": {"cam_K": [572,0,320,0,572,240,0,0,1], "depth_scale": 0.1}}"#);
    assert!(err_text(read_camera(&p, Some("7"))).contains("no frame '7'"));
    assert!(read_camera(&p, None).is_ok());
    // Two cameras in one entry: neither is picked silently.
    let p = write(d.path(), "c5.json", r#"{"cam_K": [572,0,320,0,572,240,0,0,1], "depth_scale": 0.1, "fx": 1145, "fy": 1145, "cx": 640, "cy": 480}"#);
    assert!(err_text(read_camera(&p, None)).contains("both cam_K and fx"));
    assert_eq!(read_camera(&p, None).unwrap_err().input(), None);
    // depth_scale is required (BOP depth without it has no unit) and plausible.
    let p = write(d.path(), "c5.json", r#"{"cam_K": [572,0,320,0,572,240,0,0,1]}"#);
    assert!(err_text(read_camera(&p, None)).contains("depth_scale"));
    let p = write(d.path(), "c6.json", r#"{"cam_K": [572,0,320,0,572,240,0,0,1], "depth_scale": 1e-9}"#);
    assert!(err_text(read_camera(&p, None)).contains("not a plausible scale"));
    // The BOP dataset camera.json (fx, fy, cx, cy, width, height) is read.
    let p = write(d.path(), "c7.json", r#"{"cx": 325.26, "cy": 242.05, "depth_scale": 0.1, "fx": 572.41, "fy": 573.57, "height": 480, "width": 640}"#);
    let cam = read_camera(&p, None).unwrap();
    assert_eq!(cam.cam_k, vec![572.41, 0.0, 325.26, 0.0, 573.57, 242.05, 0.0, 0.0, 1.0]);
    let p = write(d.path(), "c3.json", r#"{"cam_K": [572,0,320,0,572,240,0,0,1], "depth_scale": -1}"#);
    assert!(err_text(read_camera(&p, None)).contains("depth_scale must be positive"));
    assert!(err_text(read_camera(Path::new("/nonexistent/cam.json"), None)).contains("not found"));
}

#[test]
fn pose_files_name_what_is_wrong() {
    let d = tempfile::tempdir().unwrap();
    // A pose missing cam_t_m2c: serde names the field and the line.
    let p = write(d.path(), "p1.json", "[\n{\"cam_R_m2c\": [1,0,0,0,1,0,0,0,1]}\n]");
    let e = err_text(read_poses(&p, PoseUnits::Millimetres, false));
    assert!(e.contains("cam_t_m2c") && e.contains("line 2"), "{e}");
    // A BOP scene_gt.json: says what it is, and reads with an image and object picked.
    let gt = r#"{"3": [{"cam_R_m2c": [1,0,0,0,1,0,0,0,1], "cam_t_m2c": [0,0,700], "obj_id": 1},
                       {"cam_R_m2c": [1,0,0,0,1,0,0,0,1], "cam_t_m2c": [10,0,800], "obj_id": 5}]}"#;
    let p = write(d.path(), "scene_gt.json", gt);
    let e = err_text(read_poses(&p, PoseUnits::Millimetres, false));
    assert!(e.contains("scene_gt.json") && e.contains("image id"), "{e}");
    assert_eq!(read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().input(), Some(plausible::Input::Selection));
    let sel = plausible::pose::SceneGtSelection { frame: "3", obj_id: Some(5) };
    let poses = plausible::pose::read_poses_selected(&p, PoseUnits::Millimetres, false, Some(sel)).unwrap();
    assert_eq!(poses.len(), 1);
    assert!((poses[0].t.z - 0.8).abs() < 1e-12);
    let sel = plausible::pose::SceneGtSelection { frame: "4", obj_id: Some(5) };
    assert!(err_text(plausible::pose::read_poses_selected(&p, PoseUnits::Millimetres, false, Some(sel))).contains("no image '4'"));
}

#[test]
fn depth_png_errors() {
    let d = tempfile::tempdir().unwrap();
    // A 640x480 camera does not belong to a 64x48 image: its principal
    // point lies far outside.
    let vga = read_camera(&camera(d.path()), None).unwrap();
    let small = d.path().join("small.png");
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(64, 48, image::Luma([7000u16])).save(&small).unwrap();
    assert!(err_text(read_depth_png(&small, &vga)).contains("principal point"));
    // The K of a stream twice the size puts it just past the border: read
    // (a crop's adjusted K may do the same), with a note for the caller to
    // say.
    let vga_png = d.path().join("vga.png");
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(640, 480, image::Luma([7000u16])).save(&vga_png).unwrap();
    let double = BopCamera { cam_k: vec![1145.0, 0.0, 651.0, 0.0, 1147.0, 485.0, 0.0, 0.0, 1.0], depth_scale: 0.1, width: None, height: None };
    let note = read_depth_png(&vga_png, &double).unwrap().intrinsics.principal_point_note().unwrap();
    assert!(note.contains("outside the 640x480 image"), "{note}");
    assert!(read_depth_png(&vga_png, &vga).unwrap().intrinsics.principal_point_note().is_none());
    let cam = BopCamera { cam_k: vec![60.0, 0.0, 31.5, 0.0, 60.0, 23.5, 0.0, 0.0, 1.0], depth_scale: 0.1, width: None, height: None };
    let absurd = BopCamera { cam_k: vec![1e6, 0.0, 31.5, 0.0, 1e6, 23.5, 0.0, 0.0, 1.0], depth_scale: 0.1, width: None, height: None };
    assert!(err_text(read_depth_png(&small, &absurd)).contains("focal length"));
    assert!(read_depth_png(&small, &cam).is_ok());
    // A camera that states its image size must match the image.
    let stated = BopCamera { width: Some(64), height: Some(100), ..cam.clone() };
    assert!(err_text(read_depth_png(&small, &stated)).contains("height is 48 px, but the camera states 100"));
    assert!(read_depth_png(&small, &BopCamera { height: Some(48), ..stated }).is_ok());
    // 8-bit depth is not BOP depth.
    let p8 = d.path().join("d8.png");
    image::GrayImage::from_pixel(64, 48, image::Luma([7])).save(&p8).unwrap();
    assert!(err_text(read_depth_png(&p8, &cam)).contains("16-bit"));
    // All zero.
    let p0 = d.path().join("d0.png");
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(64, 48, image::Luma([0u16])).save(&p0).unwrap();
    assert!(err_text(read_depth_png(&p0, &cam)).contains("no valid"));
    // A depth_scale that makes depths absurd (metres where mm are expected).
    let big = BopCamera { cam_k: cam.cam_k.clone(), depth_scale: 1000.0, width: None, height: None };
    let p1 = d.path().join("d1.png");
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(64, 48, image::Luma([700u16])).save(&p1).unwrap();
    assert!(err_text(read_depth_png(&p1, &big)).contains("depth_scale"));
    // One 100 times too small (0.001 for LM-O's 0.1): 7000 units read as
    // 7 mm instead of 0.7 m would put every point at the lens.
    let tiny = BopCamera { depth_scale: 0.001, ..cam.clone() };
    let e = err_text(read_depth_png(&small, &tiny));
    assert!(e.contains("median depth is 7.0 mm") && e.contains("depth_scale 0.001"), "{e}");
    assert!(err_text(read_depth_png(Path::new("/nonexistent/d.png"), &cam)).contains("not found"));
}

#[test]
fn mask_errors() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("m.png");
    image::GrayImage::from_pixel(64, 48, image::Luma([0])).save(&p).unwrap();
    // An empty mask reads (a dataset's fully hidden instance); scoring
    // against it is refused.
    let empty = read_mask_png(&p, 64, 48).unwrap();
    assert!(err_text(plausible::observation::check_mask(&empty, 64, 48)).contains("mask is empty"));
    assert!(err_text(read_mask_png(&p, 640, 480)).contains("64x48"));
    // A 16-bit PNG is a depth image given as the mask.
    image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(64, 48, image::Luma([700u16])).save(&p).unwrap();
    assert!(err_text(read_mask_png(&p, 64, 48)).contains("depth image?"));
    // In a colour mask any non-zero channel is the object, dark blue too
    // (its luma is 0); alpha is not the mask.
    let mut rgba = image::RgbaImage::from_pixel(64, 48, image::Rgba([0, 0, 0, 255]));
    rgba.put_pixel(3, 2, image::Rgba([0, 0, 3, 255]));
    rgba.put_pixel(4, 2, image::Rgba([255, 255, 255, 255]));
    rgba.put_pixel(5, 2, image::Rgba([0, 0, 0, 0]));
    rgba.save(&p).unwrap();
    let m = read_mask_png(&p, 64, 48).unwrap();
    assert_eq!(m.iter().filter(|&&v| v).count(), 2);
    assert!(m[2 * 64 + 3] && m[2 * 64 + 4]);
}

fn poses_file(dir: &Path, body: &str) -> PathBuf {
    write(dir, "poses.json", body)
}

const GOOD_R: &str = "[1,0,0, 0,1,0, 0,0,1]";

#[test]
fn poses_nan() {
    let d = tempfile::tempdir().unwrap();
    // JSON has no NaN literal; a null or a huge number is what arrives.
    let p = poses_file(d.path(), &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0, 0, 1e999]}}]"#));
    let e = read_poses(&p, PoseUnits::Millimetres, false).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("NaN or infinity") || e.contains("number out of range"), "{e}");
    let p = poses_file(d.path(), &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0, null, 700]}}]"#));
    assert!(read_poses(&p, PoseUnits::Millimetres, false).is_err());
    // NaN built in code.
    let bad = plausible::pose::Pose::from_row_major([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], [f64::NAN, 0.0, 0.7]);
    assert!(bad.validated(3, false).unwrap_err().to_string().contains("pose 3: contains NaN"));
}

#[test]
fn poses_not_orthonormal() {
    let d = tempfile::tempdir().unwrap();
    let p = poses_file(d.path(), r#"{"poses": [{"cam_R_m2c": [1,0.01,0, 0,1,0, 0,0,1], "cam_t_m2c": [0, 0, 700]}]}"#);
    let e = read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string();
    assert!(e.contains("not orthonormal") && e.contains("--orthonormalize"), "{e}");
    let fixed = read_poses(&p, PoseUnits::Millimetres, true).unwrap();
    assert!(fixed[0].orthonormality_error() < 1e-12);
    let p = poses_file(d.path(), r#"[{"cam_R_m2c": [-1,0,0, 0,1,0, 0,0,1], "cam_t_m2c": [0, 0, 700]}]"#);
    assert!(read_poses(&p, PoseUnits::Millimetres, true).unwrap_err().to_string().contains("determinant"));
}

#[test]
fn poses_behind_camera() {
    let d = tempfile::tempdir().unwrap();
    let p = poses_file(d.path(), &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0, 0, -500]}}]"#));
    assert!(read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string().contains("behind the camera"));
    // Beyond 10 km: no camera sees it, and f32 kernels would overflow.
    let p = poses_file(d.path(), &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0, 0, 1e100]}}]"#));
    let e = read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string();
    assert!(e.contains("1.000e97 m") && e.contains("10000 m"), "{e}");
}

#[test]
fn poses_in_metres_where_millimetres_are_expected() {
    let d = tempfile::tempdir().unwrap();
    let p = poses_file(d.path(), &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0.01, 0.02, 0.7]}}]"#));
    let e = read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string();
    // The library's message names no CLI flag (the CLI adds its own).
    assert!(e.contains("look like metres") && !e.contains("--"), "{e}");
    let ok = read_poses(&p, PoseUnits::Metres, false).unwrap();
    assert!((ok[0].t.z - 0.7).abs() < 1e-12);
    // The reverse: millimetres read as metres put the object 700 m away.
    let mm = poses_file(d.path(), &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [10, 20, 700]}}]"#));
    let e = read_poses(&mm, PoseUnits::Metres, false).unwrap_err().to_string();
    assert!(e.contains("look like millimetres"), "{e}");
    // One pose in metres among poses in millimetres.
    let mixed = poses_file(
        d.path(),
        &format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0.01, 0.02, 0.7]}}, {{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [10, 20, 700]}}, {{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [10, 25, 710]}}]"#),
    );
    let e = read_poses(&mixed, PoseUnits::Millimetres, false).unwrap_err().to_string();
    assert!(e.contains("pose 0") && e.contains("another unit"), "{e}");
    // A BOP results file in metres.
    let r = write(d.path(), "r.csv", "scene_id,im_id,obj_id,score,R,t,time\n2,3,1,0.9,1 0 0 0 1 0 0 0 1,0.01 0.02 0.7,-1\n");
    let e = err_text(plausible::bop::read_results(&r));
    assert!(e.contains("r.csv") && e.contains("looks like metres"), "{e}");
}

#[test]
fn poses_malformed_json() {
    let d = tempfile::tempdir().unwrap();
    let p = poses_file(d.path(), r#"[{"R": [1]}]"#);
    assert!(read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string().contains("cam_R_m2c"));
    let p = poses_file(d.path(), r#"[{"cam_R_m2c": [1,0,0], "cam_t_m2c": [0,0,700]}]"#);
    assert!(read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string().contains("9 numbers"));
    let p = poses_file(d.path(), "[]");
    assert!(read_poses(&p, PoseUnits::Millimetres, false).unwrap_err().to_string().contains("no poses"));
}

#[test]
fn no_adapter_error_names_both_remedies() {
    let e = Context::new(&GpuOptions { adapter: Some("no-such-adapter-xyz".into()), limits: None })
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no GPU adapter") && e.contains("mesa-vulkan-drivers") && e.contains("device `cpu`"), "{e}");
}

/// Input files are read through one capped reader: an endless stream such
/// as /dev/zero is refused once past the cap (it had grown until the
/// process was killed), a pipe (process substitution) still reads, and a
/// regular file over the cap is refused by its size before reading.
#[test]
fn input_files_are_read_with_a_cap() {
    let d = tempfile::tempdir().unwrap();
    let e = err_text(plausible::io::read_capped(Path::new("/dev/zero"), 1 << 20, "pose file"));
    assert!(e.contains("/dev/zero") && e.contains("pose file") && e.contains("more than the 1 MiB a pose file"), "{e}");
    let p = write(d.path(), "big.json", &" ".repeat(2000));
    let e = err_text(plausible::io::read_capped(&p, 1000, "camera file"));
    assert!(e.contains("big.json") && e.contains("2000 bytes"), "{e}");
    assert_eq!(plausible::io::read_capped(&p, 2000, "camera file").unwrap().len(), 2000);
    assert!(err_text(plausible::io::read_capped(d.path(), 1000, "camera file")).contains("is a folder"));
    // Meshes are read whole by their parsers: a device is refused.
    let e = err_text(plausible::mesh::Mesh::load(Path::new("/dev/zero"), plausible::mesh::MeshUnits::Metres));
    assert!(e.contains("/dev/zero") && e.contains("not a regular file"), "{e}");
    // A FIFO with a writer: read to its end, as `--poses <(cat poses.json)` does.
    let fifo = d.path().join("poses.fifo");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let writer = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::write(&fifo, format!(r#"[{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [0, 0, 700]}}]"#)).unwrap())
    };
    let poses = read_poses(&fifo, PoseUnits::Millimetres, false).unwrap();
    writer.join().unwrap();
    assert_eq!(poses.len(), 1);
}

/// A UTF-8 byte order mark (written by editors on Windows) before the JSON
/// of a pose, camera or plane file is skipped, as the report does; it had
/// been refused as "not a JSON list or object" / "expected value".
#[test]
fn json_inputs_with_a_byte_order_mark() {
    let d = tempfile::tempdir().unwrap();
    let p = write(d.path(), "poses.json", &format!("\u{feff}[{{\"cam_R_m2c\": {GOOD_R}, \"cam_t_m2c\": [0, 0, 700]}}]"));
    assert_eq!(read_poses(&p, PoseUnits::Millimetres, false).unwrap().len(), 1);
    let p = write(d.path(), "camera.json", "\u{feff}{\"cam_K\": [572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 1], \"depth_scale\": 0.1}");
    assert_eq!(read_camera(&p, None).unwrap().depth_scale, 0.1);
    let p = write(d.path(), "plane.json", "\u{feff}{\"point\": [0, 0, 700], \"normal\": [0, 0, -1]}");
    assert!((plausible::physical::scene::read_camera_plane(&p).unwrap().point.z - 0.7).abs() < 1e-12);
    let cube = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/physics/cube.obj");
    let p = write(d.path(), "scene.json", &format!("\u{feff}{{\"objects\": [{{\"mesh\": \"{cube}\", \"units\": \"m\", \"R\": [1,0,0,0,1,0,0,0,1], \"t\": [0,0,0.1]}}]}}"));
    assert_eq!(plausible::physical::scene::Scene::load(&p).unwrap().objects.len(), 1);
}

/// A `{"poses": [...]}` file and a scene_gt.json are read straight from the
/// text as the list is (no `serde_json::Value` of the whole document, which
/// had taken 4.4 times the memory and 14 times the time): the same poses
/// for every form, and an error names its line, which the detour through
/// `Value` had lost.
#[test]
fn pose_objects_read_like_lists() {
    let d = tempfile::tempdir().unwrap();
    let one = |z: u32, obj: u32| format!(r#"{{"cam_R_m2c": {GOOD_R}, "cam_t_m2c": [1, 2, {z}], "obj_id": {obj}}}"#);
    let list = format!("[{}, {}]", one(700, 1), one(800, 2));
    let from_list = read_poses(&write(d.path(), "l.json", &list), PoseUnits::Millimetres, false).unwrap();
    let p = write(d.path(), "o.json", &format!(r#"{{"note": {{"x": [1, {{}}]}}, "poses": {list}, "z": null}}"#));
    assert_eq!(read_poses(&p, PoseUnits::Millimetres, false).unwrap(), from_list);
    let sel = |frame, obj_id| Some(plausible::pose::SceneGtSelection { frame, obj_id });
    let read_sel = |p: &Path, s| plausible::pose::read_poses_selected(p, PoseUnits::Millimetres, false, s);
    assert!(err_text(read_sel(&p, sel("0", None))).contains("not a BOP scene_gt.json"));
    assert_eq!(read_sel(&p, sel("0", None)).unwrap_err().input(), Some(plausible::Input::Selection));
    // A scene_gt.json: the other images are skipped, even ones no pose list.
    let gt = write(d.path(), "gt.json", &format!(r#"{{"9": {{"odd": 1}}, "12": {list}, "10": [{}]}}"#, one(900, 2)));
    assert_eq!(read_sel(&gt, sel("12", None)).unwrap(), from_list);
    assert_eq!(read_sel(&gt, sel("12", Some(2))).unwrap(), from_list[1..].to_vec());
    assert_eq!(read_sel(&gt, sel("10", Some(2))).unwrap()[0].t.z, 0.9);
    let e = err_text(read_poses(&gt, PoseUnits::Millimetres, false));
    assert!(e.contains("(3 images)") && e.contains("(e.g. 10)"), "{e}");
    assert!(err_text(read_sel(&gt, sel("11", None))).contains("no image '11'"));
    assert!(err_text(read_sel(&gt, sel("12", Some(7)))).contains("image 12 has no instance of object 7"));
    let e = err_text(read_sel(&gt, sel("9", None)));
    assert!(e.contains("image 9: invalid type") && e.contains("line 1"), "{e}");
    // A malformed pose of a {"poses": ...} file: the field and the line.
    let p = write(d.path(), "bad.json", &format!("{{\"poses\": [{},\n{{\"cam_R_m2c\": {GOOD_R}}}]}}", one(700, 1)));
    let e = err_text(read_poses(&p, PoseUnits::Millimetres, false));
    assert!(e.contains("cam_t_m2c") && e.contains("line 2"), "{e}");
    let p = write(d.path(), "trailing.json", &format!("{{\"poses\": {list}}} x"));
    assert!(err_text(read_poses(&p, PoseUnits::Millimetres, false)).contains("trailing"));
}

/// CRC-32 of PNG chunks, for the hand-made chunk below.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// A 16-bit grey depth PNG with a tRNS chunk (one grey value marked
/// transparent) is read with its depth values: the decoder expands it to
/// grey + alpha, and it had been refused as "got La16".
#[test]
fn depth_png_with_transparency_chunk() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("depth.png");
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(64, 48, |x, _| image::Luma([if x == 0 { 0 } else { 7000 + x as u16 }]));
    img.save(&p).unwrap();
    let mut bytes = std::fs::read(&p).unwrap();
    // After the signature (8 bytes) and IHDR (4 + 4 + 13 + 4): tRNS marking grey 0.
    let mut chunk = b"tRNS\x00\x00".to_vec();
    let crc = crc32(&chunk);
    chunk.extend_from_slice(&crc.to_be_bytes());
    let mut trns = 2u32.to_be_bytes().to_vec();
    trns.extend_from_slice(&chunk);
    bytes.splice(33..33, trns);
    std::fs::write(&p, &bytes).unwrap();
    assert_eq!(image::open(&p).unwrap().color(), image::ColorType::La16, "the test PNG has its tRNS chunk");
    let cam = BopCamera { cam_k: vec![60.0, 0.0, 31.5, 0.0, 60.0, 23.5, 0.0, 0.0, 1.0], depth_scale: 0.1, width: None, height: None };
    let depth = read_depth_png(&p, &cam).unwrap();
    assert_eq!(depth.depth[0], 0.0);
    assert!((depth.depth[5] - 7005.0 * 1e-4).abs() < 1e-6, "{}", depth.depth[5]);
    // A grey PNG with a real alpha channel (colour type 4) is no depth
    // image: refused, not read with its alpha dropped.
    let la = image::ImageBuffer::<image::LumaA<u16>, _>::from_fn(64, 48, |x, _| image::LumaA([7000 + x as u16, 0]));
    la.save(&p).unwrap();
    let e = read_depth_png(&p, &cam).unwrap_err().to_string();
    assert!(e.contains("La16") && e.contains("alpha channel"), "{e}");
}
