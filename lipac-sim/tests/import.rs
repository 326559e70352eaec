//! `lipac import`: small glTF files built here (JSON + base64 buffer, and
//! the same as .glb), imported as traces and replayed in geometry mode.

use std::io::Cursor;

use lipac_core::instance::{InstanceFlags, MeshId};
use lipac_core::trace::{InstanceEvent, TraceFormat};
use lipac_sim::import::camera_path::CameraSource;
use lipac_sim::import::{import_gltf, write_trace, ImportConfig, Imported};
use lipac_sim::replay::{ReplayConfig, TraceInput};
use lipac_sim::strategy::StrategyKind;
use lipac_sim::trace_scene::{replay_trace, TraceSceneOptions};

fn base64(bytes: &[u8]) -> String {
    const A: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// The binary buffer and the JSON's accessor/bufferView parts: a unit cube
/// (u16 indices), an 8 x 8 flat grid (u32 indices) and three instancing
/// translations.
fn buffer() -> (Vec<u8>, String) {
    let mut bin = Vec::new();
    let mut views = Vec::new();
    let mut push = |bin: &mut Vec<u8>, data: Vec<u8>| {
        views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":{}}}"#,
            bin.len(),
            data.len()
        ));
        bin.extend(data);
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
    };
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let mut cube = Vec::new();
    for i in 0..8 {
        cube.extend([
            if i & 1 != 0 { 0.5 } else { -0.5 },
            if i & 2 != 0 { 2.0 } else { 0.0 },
            if i & 4 != 0 { 0.5 } else { -0.5 },
        ]);
    }
    let quads: [[u16; 4]; 6] = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let cube_ix: Vec<u8> = quads
        .iter()
        .flat_map(|q| [q[0], q[1], q[2], q[0], q[2], q[3]])
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let n = 8u32;
    let mut grid = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            grid.extend([i as f32 - 4.0, 0.0, j as f32 - 4.0]);
        }
    }
    let mut grid_ix = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            grid_ix.extend([a, a + n + 1, a + 1, a + 1, a + n + 1, a + n + 2]);
        }
    }
    let grid_ix: Vec<u8> = grid_ix.iter().flat_map(|i| i.to_le_bytes()).collect();
    let crowd = [-2.0f32, 0.0, 3.0, 0.0, 0.0, 3.0, 2.0, 0.0, 3.0];
    push(&mut bin, f32s(&cube));
    push(&mut bin, cube_ix);
    push(&mut bin, f32s(&grid));
    push(&mut bin, grid_ix);
    push(&mut bin, f32s(&crowd));
    let accessors = r#"[
 {"bufferView":0,"componentType":5126,"count":8,"type":"VEC3","min":[-0.5,0,-0.5],"max":[0.5,2,0.5]},
 {"bufferView":1,"componentType":5123,"count":36,"type":"SCALAR"},
 {"bufferView":2,"componentType":5126,"count":81,"type":"VEC3","min":[-4,0,-4],"max":[4,0,4]},
 {"bufferView":3,"componentType":5125,"count":384,"type":"SCALAR"},
 {"bufferView":4,"componentType":5126,"count":3,"type":"VEC3"}]"#;
    let parts = format!(
        r#""accessors":{accessors},"bufferViews":[{}]"#,
        views.join(",")
    );
    (bin, parts)
}

/// The glTF JSON (`buffer` is the buffers array), with or without a camera.
fn json(parts: &str, buffers: &str, camera: bool) -> String {
    let cam_node = if camera {
        r#",{"name":"eye","camera":0,"translation":[10,8,20],"rotation":[-0.14943813,0,0,0.98877108]}"#
    } else {
        ""
    };
    let cams = if camera {
        r#","cameras":[{"type":"perspective","perspective":{"yfov":1.0,"znear":0.1}}]"#
    } else {
        ""
    };
    let roots = if camera { "[0,4,5]" } else { "[0,4]" };
    format!(
        r#"{{"asset":{{"version":"2.0"}},"extensionsUsed":["EXT_mesh_gpu_instancing"],
"scene":0,"scenes":[{{"nodes":{roots}}}],
"nodes":[
 {{"name":"city","translation":[10,0,0],"children":[1,2,3]}},
 {{"name":"house","mesh":0,"translation":[0,0,-5]}},
 {{"name":"tree_oak","mesh":0,"translation":[3,0,-8],"scale":[0.5,2,0.5]}},
 {{"name":"crowd","mesh":0,"extras":{{"lipac":{{"animated":true}}}},
   "extensions":{{"EXT_mesh_gpu_instancing":{{"attributes":{{"TRANSLATION":4}}}}}}}},
 {{"name":"ground","mesh":1,"extras":{{"lipac":{{"pinned":true}}}},"scale":[4,1,4]}}{cam_node}],
"meshes":[
 {{"name":"box","primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}},
 {{"name":"terrain","primitives":[{{"attributes":{{"POSITION":2}},"indices":3}}]}}],
{parts},"buffers":{buffers}{cams}}}"#
    )
}

fn gltf_file(camera: bool) -> Vec<u8> {
    let (bin, parts) = buffer();
    let buffers = format!(
        r#"[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{}"}}]"#,
        bin.len(),
        base64(&bin)
    );
    json(&parts, &buffers, camera).into_bytes()
}

fn glb_file(camera: bool) -> Vec<u8> {
    let (bin, parts) = buffer();
    let mut j = json(
        &parts,
        &format!(r#"[{{"byteLength":{}}}]"#, bin.len()),
        camera,
    )
    .into_bytes();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let total = 12 + 8 + j.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((j.len() as u32).to_le_bytes());
    out.extend(0x4E4F_534Au32.to_le_bytes());
    out.extend(j);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(0x004E_4942u32.to_le_bytes());
    out.extend(bin);
    out
}

fn import(bytes: &[u8], frames: u32) -> Imported {
    let config = ImportConfig {
        frames,
        ..ImportConfig::default()
    };
    import_gltf(bytes, None, "test scene", &config).unwrap()
}

fn translation(e: &InstanceEvent) -> [f32; 3] {
    match e {
        InstanceEvent::Add(a) => [
            a.pose.transform[3],
            a.pose.transform[7],
            a.pose.transform[11],
        ],
        _ => panic!("not an add: {e:?}"),
    }
}

#[test]
fn hierarchy_instancing_lods_and_flags_are_imported() {
    let im = import(&gltf_file(false), 4);
    let s = &im.summary;
    assert_eq!((s.meshes, s.instances, s.gpu_instanced), (2, 6, 3));
    assert_eq!((s.vegetation, s.animated, s.pinned), (1, 3, 1));
    // The pinned node's instance (the ground, mesh 1) and only it carries
    // lipac-core's PINNED flag.
    let frame0 = im.frames().next().unwrap();
    let adds: Vec<_> = frame0
        .events
        .iter()
        .filter_map(|e| match e {
            InstanceEvent::Add(a) => Some(a),
            _ => None,
        })
        .collect();
    assert_eq!(adds.len(), 6);
    for a in adds {
        assert_eq!(
            a.flags.contains(InstanceFlags::PINNED),
            a.mesh == MeshId(1),
            "{a:?}"
        );
    }
    assert!(!s.file_cameras);
    // Three LODs with geometry; the flat grid simplifies, nothing grows.
    for m in &im.header.meshes {
        assert_eq!(m.lods.len(), 3);
        assert!(m.lods.iter().all(|l| l.geometry.is_some()));
        assert!(m.lods[1].triangles <= m.lods[0].triangles);
        assert!(m.lods[2].triangles <= m.lods[1].triangles);
    }
    assert_eq!(im.header.meshes[1].lods[0].triangles, 128);
    assert!(im.header.meshes[1].lods[1].triangles < 128);
    // Frame 0 adds everything at its world transform.
    let f0 = &im.frames().next().unwrap().events;
    assert_eq!(f0.len(), 6);
    assert_eq!(translation(&f0[0]), [10.0, 0.0, -5.0]); // city * house
    assert_eq!(translation(&f0[1]), [13.0, 0.0, -8.0]); // city * tree
    assert_eq!(translation(&f0[2]), [8.0, 0.0, 3.0]); // city * crowd[0]
    assert_eq!(translation(&f0[4]), [12.0, 0.0, 3.0]); // city * crowd[2]
    let flags = |e: &InstanceEvent| match e {
        InstanceEvent::Add(a) => a.flags,
        _ => unreachable!(),
    };
    assert_eq!(
        flags(&f0[1]),
        InstanceFlags::VEGETATION | InstanceFlags::STATIC
    );
    assert_eq!(flags(&f0[0]), InstanceFlags::STATIC);
    assert_eq!(flags(&f0[2]), InstanceFlags::empty());
    // The animated crowd moves every later frame.
    let moved = im
        .frames()
        .nth(1)
        .unwrap()
        .events
        .iter()
        .filter(|e| matches!(e, InstanceEvent::Update(u) if u.pose.is_some()))
        .count();
    assert_eq!(moved, 3);
}

#[test]
fn glb_and_embedded_gltf_import_alike_and_file_cameras_are_used() {
    let a = import(&gltf_file(true), 3);
    let b = import(&glb_file(true), 3);
    assert_eq!(a, b);
    assert!(a.summary.file_cameras);
    assert_eq!(
        a.frames().next().unwrap().camera.position.to_array(),
        [10.0, 8.0, 20.0]
    );
    assert_eq!(a.frames().next().unwrap().camera.vertical_fov, 1.0);
    let orbit = import_gltf(
        &gltf_file(true),
        None,
        "t",
        &ImportConfig {
            frames: 3,
            camera: CameraSource::Orbit,
            ..ImportConfig::default()
        },
    )
    .unwrap();
    assert_ne!(
        orbit.frames().next().unwrap().camera.position,
        a.frames().next().unwrap().camera.position
    );
    // An external buffer without a base folder is a clear error.
    let (_, parts) = buffer();
    let ext = json(&parts, r#"[{"byteLength":4,"uri":"scene.bin"}]"#, false);
    let e = import_gltf(ext.as_bytes(), None, "t", &ImportConfig::default()).unwrap_err();
    assert!(e.to_string().contains("scene.bin"), "{e}");
}

#[test]
fn an_imported_scene_replays_with_zero_error_for_full_and_oracle() {
    for (camera, format) in [(false, TraceFormat::Binary), (true, TraceFormat::Jsonl)] {
        let im = import(&gltf_file(camera), 5);
        let bytes = write_trace(&im, format, Vec::new()).unwrap();
        let config = ReplayConfig {
            strategies: vec![
                StrategyKind::Full,
                StrategyKind::Oracle,
                StrategyKind::Lipac,
            ],
            width: 40,
            height: 24,
            threads: 2,
            ..ReplayConfig::default()
        };
        let r = replay_trace(
            || TraceInput::new(format, Cursor::new(&bytes[..])),
            &config,
            &TraceSceneOptions::default(),
            &mut |_| {},
        )
        .unwrap();
        assert_eq!(r.report.frames, 5);
        assert_eq!(r.report.instances, 6);
        assert!(r.box_proxies.is_empty());
        let full = r.report.strategy("full").unwrap();
        assert!(full.frames.iter().all(|m| m.error == 0.0));
        let oracle = r.report.strategy("oracle").unwrap();
        assert!(
            oracle.frames.iter().all(|m| m.error == 0.0),
            "{:?}",
            oracle.summary
        );
        // The scene is seen: the ground truth traced bounce and shadow rays.
        assert!(r.report.traced_rays_per_frame > 0.0);
    }
}

#[test]
fn msft_lod_levels_are_the_files_not_generated() {
    let mut doc: serde_json::Value = serde_json::from_slice(&gltf_file(false)).unwrap();
    let nodes = doc["nodes"].as_array_mut().unwrap();
    // The house's coarser level is node 5 (the terrain mesh, to tell it
    // apart); LOD nodes are outside the scene's hierarchy.
    nodes.push(serde_json::json!({"name": "house_lod1", "mesh": 1}));
    nodes[1]["extensions"] = serde_json::json!({"MSFT_lod": {"ids": [5]}});
    let im = import(&serde_json::to_vec(&doc).unwrap(), 2);
    assert_eq!(im.summary.file_lods, 1);
    // box (tree, crowd), box with its file LOD (house), terrain.
    assert_eq!(im.summary.meshes, 3);
    assert_eq!(im.summary.instances, 6);
    let house_mesh = match &im.frames().next().unwrap().events[0] {
        InstanceEvent::Add(a) => a.mesh,
        e => panic!("{e:?}"),
    };
    let m = im
        .header
        .meshes
        .iter()
        .find(|m| m.id == house_mesh)
        .unwrap();
    let tris: Vec<u32> = m.lods.iter().map(|l| l.triangles).collect();
    assert_eq!(tris, vec![12, 128]);
    // Generated LODs elsewhere: three levels.
    assert!(im
        .header
        .meshes
        .iter()
        .filter(|m| m.id != house_mesh)
        .all(|m| m.lods.len() == 3));
    let bytes = write_trace(&im, TraceFormat::Binary, Vec::new()).unwrap();
    let r = replay_trace(
        || TraceInput::new(TraceFormat::Binary, Cursor::new(&bytes[..])),
        &ReplayConfig {
            strategies: vec![StrategyKind::Full],
            width: 16,
            height: 9,
            threads: 1,
            ..ReplayConfig::default()
        },
        &TraceSceneOptions::default(),
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(r.report.frames, 2);
}

#[test]
fn cli_imports_a_glb_and_replays_it_with_the_error() {
    let dir = std::env::temp_dir().join(format!("lipac-import-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let glb = dir.join("scene.glb");
    std::fs::write(&glb, glb_file(true)).unwrap();
    let trace = dir.join("scene.lipactrace");
    let lipac = env!("CARGO_BIN_EXE_lipac");
    let out = std::process::Command::new(lipac)
        .args(["import", "--frames", "4"])
        .arg(&glb)
        .arg(&trace)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("6 instances (3 GPU-instanced"), "{stdout}");
    assert!(stdout.contains("cameras from the file"), "{stdout}");
    let report = dir.join("report");
    let out = std::process::Command::new(lipac)
        .arg("replay")
        .arg(&trace)
        .args([
            "--strategies",
            "full,oracle",
            "--width",
            "24",
            "--height",
            "16",
        ])
        .args(["--threads", "1", "--snapshots", "2", "--out"])
        .arg(&report)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(report.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["frames"], 4);
    assert_eq!(json["scene"], "gltf:scene.glb");
    let full = json["strategies"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == "full")
        .unwrap();
    assert_eq!(full["summary"]["max_error"], 0.0);
    let named = |json: &serde_json::Value, name: &str| {
        json["strategies"]
            .as_array()
            .unwrap()
            .iter()
            .find(|s| s["name"] == name)
            .unwrap()["summary"]["max_error"]
            .clone()
    };
    assert_eq!(named(&json, "oracle"), 0.0);
    // Snapshots work on trace-backed replays too.
    assert!(report.join("snapshots/frame-0002").is_dir());
    // The same trace through a pipe (`replay -`) replays with geometry too.
    let piped = dir.join("piped-report");
    let mut child = std::process::Command::new(lipac)
        .args([
            "replay",
            "-",
            "--strategies",
            "full,oracle",
            "--width",
            "24",
        ])
        .args(["--height", "16", "--threads", "1", "--out"])
        .arg(&piped)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let bytes = std::fs::read(&trace).unwrap();
    let feeder = std::thread::spawn(move || {
        use std::io::Write;
        stdin.write_all(&bytes).unwrap();
    });
    let out = child.wait_with_output().unwrap();
    feeder.join().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let piped: serde_json::Value =
        serde_json::from_slice(&std::fs::read(piped.join("report.json")).unwrap()).unwrap();
    assert_eq!(piped["frames"], 4);
    assert_eq!(piped["scene"], "gltf:scene.glb");
    assert_eq!(named(&piped, "oracle"), 0.0);
    assert_eq!(named(&piped, "full"), 0.0);
    // A missing input fails cleanly and leaves no output behind.
    let missing = dir.join("missing.lipactrace");
    let out = std::process::Command::new(lipac)
        .arg("import")
        .arg(dir.join("nope.glb"))
        .arg(&missing)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("nope.glb"));
    assert!(!missing.exists());
    let _ = std::fs::remove_dir_all(&dir);
}

/// A one-triangle glTF (embedded 44-byte buffer) whose index accessor is
/// `indices` (JSON) over a view of `view_bytes` bytes.
fn one_triangle(indices: &str, view_bytes: usize) -> Vec<u8> {
    let mut bin: Vec<u8> = [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    bin.extend([0u16, 1, 2, 0].iter().flat_map(|v| v.to_le_bytes()));
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0}}],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,0,1]}},{indices}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},{{"buffer":0,"byteOffset":36,"byteLength":{view_bytes}}}],
"buffers":[{{"byteLength":44,"uri":"data:application/octet-stream;base64,{}"}}]}}"#,
        base64(&bin)
    )
    .into_bytes()
}

/// An accessor is checked against its view before it is read: the gltf
/// crate reads as many elements as fit and stops without a word (2^40
/// indices in a 6-byte view imported as one triangle), or panics.
#[test]
fn accessors_that_overrun_their_view_are_errors() {
    let config = ImportConfig {
        frames: 1,
        ..ImportConfig::default()
    };
    let good = r#"{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}"#;
    let im = import_gltf(&one_triangle(good, 6), None, "t", &config).unwrap();
    assert_eq!(im.summary.triangles[0], 1);
    for (indices, view, expect) in [
        (
            r#"{"bufferView":1,"componentType":5123,"count":1099511627776,"type":"SCALAR"}"#,
            6,
            "overrun",
        ),
        (
            r#"{"bufferView":1,"componentType":5123,"count":4,"type":"SCALAR"}"#,
            6,
            "overrun",
        ),
        (
            r#"{"bufferView":1,"byteOffset":2,"componentType":5123,"count":3,"type":"SCALAR"}"#,
            6,
            "overrun",
        ),
        // A view beyond its buffer.
        (good, 4000, "overruns buffer"),
        // Float indices (the crate's reader would panic).
        (
            r#"{"bufferView":1,"componentType":5126,"count":1,"type":"SCALAR"}"#,
            6,
            "unsigned SCALAR",
        ),
        // Sparse without a base view: a billion zeros not from the file.
        (
            r#"{"componentType":5123,"count":1000000000,"type":"SCALAR","sparse":{"count":1,"indices":{"bufferView":1,"componentType":5123},"values":{"bufferView":1}}}"#,
            6,
            "no buffer view",
        ),
    ] {
        let e = import_gltf(&one_triangle(indices, view), None, "t", &config).unwrap_err();
        assert!(e.to_string().contains(expect), "{indices}: {e}");
    }
}

/// Frames are made one at a time: a trace of many frames costs the scene's
/// memory, not the frames'.
#[test]
fn frames_are_generated_as_they_are_written() {
    let config = ImportConfig {
        frames: u32::MAX,
        ..ImportConfig::default()
    };
    let good = r#"{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}"#;
    let im = import_gltf(&one_triangle(good, 6), None, "t", &config).unwrap();
    let mut frames = im.frames();
    assert_eq!(frames.len(), u32::MAX as usize);
    assert_eq!(frames.nth(1_000).unwrap().number, 1_000);
}
