//! glTF 2.0 (`.gltf` with embedded base64 or sibling buffers, or `.glb`)
//! to an [`ImportedScene`]: triangle meshes, instances with world
//! transforms (node hierarchy and `EXT_mesh_gpu_instancing`), coarser
//! LODs from `MSFT_lod`, cameras, and per-instance names and extras for the
//! flag mapping.
//!
//! Parsed with the `gltf` crate without its `import` feature: buffers are
//! the `.glb` binary chunk, `data:` URIs (base64, decoded here) or files
//! next to the `.gltf` (only when a base folder is given). Images and
//! materials are not read. Non-triangle primitives (points, lines, strips,
//! fans) are skipped and counted.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ::gltf::accessor::Iter as AccessorIter;
use ::gltf::buffer::Source;
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::{Document, Gltf, Node};
use glam::{Affine3A, Mat4, Quat, Vec3};

use crate::error::SimError;

/// One mesh: all triangle primitives of a glTF mesh, merged.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImportedMesh {
    /// The mesh's name (empty if none).
    pub name: String,
    /// Vertex positions, object space.
    pub positions: Vec<[f32; 3]>,
    /// Three indices per triangle.
    pub indices: Vec<u32>,
    /// Coarser LODs from the file (`MSFT_lod` on the placing node), finest
    /// first; empty when the file has none.
    pub lods: Vec<ImportedLod>,
}

/// One coarser LOD of an [`ImportedMesh`] from the file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImportedLod {
    /// Vertex positions, object space.
    pub positions: Vec<[f32; 3]>,
    /// Three indices per triangle.
    pub indices: Vec<u32>,
}

/// One placed mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportedInstance {
    /// Index into [`ImportedScene::meshes`].
    pub mesh: usize,
    /// Object-to-world transform.
    pub transform: Affine3A,
    /// The placing node and its ancestors, shared by the node's instances
    /// (names and extras for the flag mapping).
    pub node: Arc<NodePath>,
    /// The mesh's name (empty if none).
    pub mesh_name: Arc<str>,
    /// Placed through `EXT_mesh_gpu_instancing`.
    pub gpu_instanced: bool,
}

impl ImportedInstance {
    /// Names of the node and its ancestors, innermost first, then the
    /// mesh's name (for name patterns).
    pub fn names(&self) -> impl Iterator<Item = &str> + Clone {
        self.node
            .nodes()
            .map(|n| n.name.as_ref())
            .chain(std::iter::once(self.mesh_name.as_ref()))
    }

    /// The `extras` (raw JSON) of the node and its ancestors that have
    /// them, innermost first.
    pub fn extras(&self) -> impl Iterator<Item = &str> {
        self.node.nodes().filter_map(|n| n.extras.as_deref())
    }
}

/// A node of the glTF hierarchy with its parent's path: each node holds
/// its own name and extras once (a node's instances and children share
/// it), so names and extras cost what the file holds whatever the depth or
/// the number of instances.
#[derive(Clone, Debug, PartialEq)]
pub struct NodePath {
    /// The node's name (empty if none).
    pub name: Arc<str>,
    /// The node's `extras`, raw JSON.
    pub extras: Option<Arc<str>>,
    /// The parent's path (`None` for a root).
    pub parent: Option<Arc<NodePath>>,
}

impl NodePath {
    /// This node, then its ancestors.
    pub fn nodes(&self) -> impl Iterator<Item = &NodePath> + Clone {
        std::iter::successors(Some(self), |n| n.parent.as_deref())
    }
}

/// A camera node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportedCamera {
    /// Eye position.
    pub position: Vec3,
    /// Local-to-world rotation (looks along local −Z, +Y up, as glTF and
    /// the trace format).
    pub orientation: Quat,
    /// Vertical field of view, radians (perspective cameras; orthographic
    /// ones get 1 rad).
    pub vertical_fov: f32,
    /// The file's aspect ratio, if it gives one.
    pub aspect: Option<f32>,
}

/// What a glTF file holds, flattened.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImportedScene {
    /// The placed meshes with at least one triangle, in order of first
    /// placement (one per glTF mesh and `MSFT_lod` LOD list).
    pub meshes: Vec<ImportedMesh>,
    /// Every placed mesh.
    pub instances: Vec<ImportedInstance>,
    /// Camera nodes in traversal order.
    pub cameras: Vec<ImportedCamera>,
    /// Primitives skipped (not triangle lists, or without positions).
    pub skipped_primitives: usize,
    /// The external buffer files read (beside a `.gltf`).
    pub files_read: Vec<PathBuf>,
}

/// A node still to visit: the node, its parent's world transform, its
/// ancestors' names and extras (innermost first), its depth.
type Pending<'a> = (Node<'a>, Affine3A, Option<Arc<NodePath>>, u32);

fn err(what: impl std::fmt::Display) -> SimError {
    SimError::Import(what.to_string())
}

/// Decodes standard base64 (padding optional, no whitespace).
pub fn decode_base64(s: &str) -> Result<Vec<u8>, SimError> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => break,
            _ => return Err(err(format!("invalid base64 character {:?}", c as char))),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

fn load_buffers(
    doc: &Document,
    blob: Option<&[u8]>,
    base: Option<&Path>,
    files_read: &mut Vec<PathBuf>,
) -> Result<Vec<Vec<u8>>, SimError> {
    let mut out = Vec::new();
    for b in doc.buffers() {
        let data = match b.source() {
            Source::Bin => blob
                .ok_or_else(|| {
                    err(format!(
                        "buffer {} refers to a missing GLB chunk",
                        b.index()
                    ))
                })?
                .to_vec(),
            Source::Uri(uri) if uri.starts_with("data:") => {
                let (_, payload) = uri.split_once(";base64,").ok_or_else(|| {
                    err(format!(
                        "buffer {}: only base64 data URIs are read",
                        b.index()
                    ))
                })?;
                decode_base64(payload)?
            }
            Source::Uri(uri) => {
                let base = base.ok_or_else(|| {
                    err(format!(
                        "buffer {} is the external file {uri:?}; embed it (data URI or .glb)",
                        b.index()
                    ))
                })?;
                if uri.contains("..") || uri.starts_with('/') || uri.contains(':') {
                    return Err(err(format!(
                        "buffer {} URI {uri:?} is not a plain relative file name",
                        b.index()
                    )));
                }
                let p = base.join(uri);
                files_read.push(p.clone());
                std::fs::read(&p).map_err(|e| err(format!("{}: {e}", p.display())))?
            }
        };
        if data.len() < b.length() {
            return Err(err(format!(
                "buffer {} holds {} bytes, the file says {}",
                b.index(),
                data.len(),
                b.length()
            )));
        }
        out.push(data);
    }
    Ok(out)
}

/// The geometry an import may hold: a small multiple of the file's buffer
/// bytes. Accessors shared by many primitives, or a mesh placed with many
/// different `MSFT_lod` lists (each a trace mesh of its own, its geometry
/// copied), would otherwise multiply a small file into any amount of
/// memory (and of trace).
struct GeometryBudget {
    left: u64,
    limit: u64,
    buffer_bytes: u64,
}

impl GeometryBudget {
    /// Times the buffer bytes, plus [`GeometryBudget::SLACK`].
    const FACTOR: u64 = 8;
    const SLACK: u64 = 16 << 20;

    fn new(buffers: &[Vec<u8>]) -> Self {
        let buffer_bytes: u64 = buffers.iter().map(|b| b.len() as u64).sum();
        let limit = buffer_bytes
            .saturating_mul(Self::FACTOR)
            .saturating_add(Self::SLACK);
        Self {
            left: limit,
            limit,
            buffer_bytes,
        }
    }

    /// Takes room for `vertices` positions and `indices` indices before
    /// they are copied.
    fn take(&mut self, vertices: usize, indices: usize) -> Result<(), SimError> {
        let bytes = (vertices as u64)
            .saturating_mul(12)
            .saturating_add((indices as u64).saturating_mul(4));
        self.left = self.left.checked_sub(bytes).ok_or_else(|| {
            err(format!(
                "the meshes as placed take more than {} bytes of geometry, {} x the file's {} \
                 buffer bytes (accessors shared by many primitives, or meshes placed with many \
                 different MSFT_lod lists)",
                self.limit,
                Self::FACTOR,
                self.buffer_bytes
            ))
        })?;
        Ok(())
    }
}

/// What an accessor must hold to be read as the import reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Elements {
    /// Float `VEC3` (positions, instance translations and scales).
    Vec3F32,
    /// Float `VEC4` (instance rotations).
    Vec4F32,
    /// Unsigned `SCALAR` of 8, 16 or 32 bits (triangle indices).
    Indices,
}

/// Checks accessor `a` before anything is read from it: its element type
/// is `want`, it has a buffer view (its elements come from the file), and
/// `count` elements of its stride, from its offset, lie within the view,
/// the view within its buffer (for a sparse accessor: its index and value
/// arrays too), in checked arithmetic. The gltf crate would read as many
/// elements as fit and stop without a word (an index accessor claiming
/// 2^40 indices in a 6-byte view read as one triangle), or panic on a
/// stride below the element size. `what` names the accessor's use.
fn check_accessor(
    a: &::gltf::Accessor<'_>,
    buffers: &[Vec<u8>],
    want: Elements,
    what: &str,
) -> Result<(), SimError> {
    use ::gltf::accessor::{DataType, Dimensions};
    let bad = |why: String| err(format!("{what} (accessor {}): {why}", a.index()));
    let ok_type = match want {
        Elements::Vec3F32 => a.data_type() == DataType::F32 && a.dimensions() == Dimensions::Vec3,
        Elements::Vec4F32 => a.data_type() == DataType::F32 && a.dimensions() == Dimensions::Vec4,
        Elements::Indices => {
            matches!(a.data_type(), DataType::U8 | DataType::U16 | DataType::U32)
                && a.dimensions() == Dimensions::Scalar
        }
    };
    if !ok_type {
        return Err(bad(format!(
            "{:?} {:?} elements, expected {}",
            a.data_type(),
            a.dimensions(),
            match want {
                Elements::Vec3F32 => "float VEC3",
                Elements::Vec4F32 => "float VEC4",
                Elements::Indices => "unsigned SCALAR",
            }
        )));
    }
    let view = a.view().ok_or_else(|| {
        bad(format!(
            "no buffer view: its {} elements would not come from the file",
            a.count()
        ))
    })?;
    check_span(&view, a.offset(), a.count(), a.size(), buffers).map_err(bad)?;
    if let Some(sparse) = a.sparse() {
        let n = sparse.count();
        if n > a.count() {
            return Err(bad(format!(
                "{n} sparse elements of an accessor of {}",
                a.count()
            )));
        }
        let indices = sparse.indices();
        check_span(
            &indices.view(),
            indices.offset(),
            n,
            indices.index_type().size(),
            buffers,
        )
        .map_err(|e| bad(format!("sparse indices: {e}")))?;
        let values = sparse.values();
        check_span(&values.view(), values.offset(), n, a.size(), buffers)
            .map_err(|e| bad(format!("sparse values: {e}")))?;
    }
    Ok(())
}

/// `count` elements of `size` bytes at `offset` in `view` (its stride, or
/// packed) lie within the view, and the view within its loaded buffer.
fn check_span(
    view: &::gltf::buffer::View<'_>,
    offset: usize,
    count: usize,
    size: usize,
    buffers: &[Vec<u8>],
) -> Result<(), String> {
    let stride = view.stride().unwrap_or(size);
    if count == 0 {
        return Err("count 0 (glTF requires at least 1)".into());
    }
    if stride < size {
        return Err(format!("stride {stride} below the element size {size}"));
    }
    let end = (count - 1)
        .checked_mul(stride)
        .and_then(|b| b.checked_add(size))
        .and_then(|b| b.checked_add(offset));
    let view_len = view.length();
    match end {
        Some(end) if end <= view_len => {}
        _ => {
            return Err(format!(
                "{count} elements of {size} bytes (stride {stride}) from offset {offset} \
                 overrun its buffer view {} of {view_len} bytes",
                view.index()
            ))
        }
    }
    let held = buffers.get(view.buffer().index()).map_or(0, Vec::len);
    match view.offset().checked_add(view_len) {
        Some(end) if end <= held => Ok(()),
        _ => Err(format!(
            "buffer view {} ({view_len} bytes from offset {}) overruns buffer {} of {held} bytes",
            view.index(),
            view.offset(),
            view.buffer().index()
        )),
    }
}

/// Reads a glTF file's bytes (`.gltf` JSON or `.glb`); external buffer
/// files are looked up in `base` (none: only embedded buffers).
pub fn read_gltf(bytes: &[u8], base: Option<&Path>) -> Result<ImportedScene, SimError> {
    let gltf = Gltf::from_slice(bytes).map_err(|e| err(format!("glTF: {e}")))?;
    let doc = &gltf.document;
    let mut scene = ImportedScene::default();
    let buffers = load_buffers(doc, gltf.blob.as_deref(), base, &mut scene.files_read)?;
    let get = |b: ::gltf::Buffer<'_>| buffers.get(b.index()).map(Vec::as_slice);
    let mut geometry = GeometryBudget::new(&buffers);

    // glTF mesh index -> imported mesh index.
    let mut base_meshes: Vec<Option<ImportedMesh>> = vec![None; doc.meshes().len()];
    for m in doc.meshes() {
        let mut out = ImportedMesh {
            name: m.name().unwrap_or_default().to_string(),
            ..ImportedMesh::default()
        };
        for p in m.primitives() {
            let at = |what: &str| format!("mesh {} primitive {} {what}", m.index(), p.index());
            let position_accessor = match (p.mode(), p.get(&Semantic::Positions)) {
                (Mode::Triangles, Some(a)) => a,
                _ => {
                    scene.skipped_primitives += 1;
                    continue;
                }
            };
            // Every accessor checked against its view before it is read:
            // the gltf crate reads what fits and stops without a word.
            check_accessor(
                &position_accessor,
                &buffers,
                Elements::Vec3F32,
                &at("POSITION"),
            )?;
            let index_accessor = p.indices();
            if let Some(a) = &index_accessor {
                check_accessor(a, &buffers, Elements::Indices, &at("indices"))?;
            }
            let r = p.reader(get);
            let positions = r
                .read_positions()
                .ok_or_else(|| err(format!("{}: cannot be read", at("POSITION"))))?;
            let base = out.positions.len() as u32;
            let start = out.positions.len();
            let count = u32::try_from(position_accessor.count())
                .ok()
                .filter(|&c| u64::from(c) + u64::from(base) <= u64::from(u32::MAX))
                .ok_or_else(|| err(format!("{}: more than 2^32 vertices", at("POSITION"))))?;
            let indices = index_accessor
                .as_ref()
                .map_or(count as usize, |a| a.count());
            geometry.take(count as usize, indices)?;
            out.positions.extend(positions);
            if out.positions.len() - start != count as usize {
                return Err(err(format!(
                    "{}: {} of its {count} positions read",
                    at("POSITION"),
                    out.positions.len() - start
                )));
            }
            match r.read_indices() {
                Some(ix) => {
                    for i in ix.into_u32() {
                        if i >= count {
                            return Err(err(format!(
                                "mesh {} primitive {}: index {i} >= {count} vertices",
                                m.index(),
                                p.index()
                            )));
                        }
                        out.indices.push(base + i);
                    }
                }
                None if index_accessor.is_some() => {
                    return Err(err(format!("{}: cannot be read", at("indices"))))
                }
                None => out.indices.extend(base..base + count),
            }
            let whole = out.indices.len() / 3 * 3;
            out.indices.truncate(whole);
        }
        if let Some((i, p)) = out
            .positions
            .iter()
            .enumerate()
            .find(|(_, p)| !p.iter().all(|v| v.is_finite()))
        {
            return Err(err(format!(
                "mesh {}: position {i} is not finite ({p:?})",
                m.index()
            )));
        }
        if !out.indices.is_empty() {
            base_meshes[m.index()] = Some(out);
        }
    }

    let roots: Vec<Node<'_>> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => doc.nodes().collect(),
    };
    // (glTF mesh, MSFT_lod meshes) -> imported mesh.
    let mut placed_meshes: HashMap<(usize, Vec<usize>), usize> = HashMap::new();
    let mut stack: Vec<Pending<'_>> = roots
        .into_iter()
        .rev()
        .map(|n| (n, Affine3A::IDENTITY, None, 0))
        .collect();
    while let Some((node, parent, parent_path, depth)) = stack.pop() {
        if depth > 256 {
            return Err(err("node hierarchy deeper than 256 (a cycle?)"));
        }
        let local = Affine3A::from_mat4(Mat4::from_cols_array_2d(&node.transform().matrix()));
        let world = parent * local;
        if !world.is_finite() {
            return Err(err(format!(
                "node {}: transform is not finite",
                node.index()
            )));
        }
        let path = Arc::new(NodePath {
            name: Arc::from(node.name().unwrap_or_default()),
            extras: node.extras().as_ref().map(|r| Arc::from(r.get())),
            parent: parent_path,
        });
        if let Some(c) = node.camera() {
            let (_, rotation, translation) = world.to_scale_rotation_translation();
            let (fov, aspect) = match c.projection() {
                ::gltf::camera::Projection::Perspective(p) => (p.yfov(), p.aspect_ratio()),
                ::gltf::camera::Projection::Orthographic(_) => (1.0, None),
            };
            scene.cameras.push(ImportedCamera {
                position: translation,
                orientation: rotation.normalize(),
                vertical_fov: fov,
                aspect,
            });
        }
        if let Some(m) = node.mesh() {
            if let Some(base) = &base_meshes[m.index()] {
                let lod_meshes = msft_lods(doc, &node, &base_meshes)?;
                let key = (m.index(), lod_meshes);
                let mesh = match placed_meshes.get(&key) {
                    Some(&i) => i,
                    None => {
                        for m in std::iter::once(m.index()).chain(key.1.iter().copied()) {
                            if let Some(g) = &base_meshes[m] {
                                geometry.take(g.positions.len(), g.indices.len())?;
                            }
                        }
                        let mut out = base.clone();
                        out.lods = key
                            .1
                            .iter()
                            .filter_map(|&lm| base_meshes[lm].as_ref())
                            .map(|l| ImportedLod {
                                positions: l.positions.clone(),
                                indices: l.indices.clone(),
                            })
                            .collect();
                        scene.meshes.push(out);
                        placed_meshes.insert(key, scene.meshes.len() - 1);
                        scene.meshes.len() - 1
                    }
                };
                let mesh_name: Arc<str> = Arc::from(m.name().unwrap_or_default());
                let placements = gpu_instances(doc, &node, &get, &buffers)?;
                let gpu = placements.is_some();
                for t in placements.unwrap_or_else(|| vec![Affine3A::IDENTITY]) {
                    scene.instances.push(ImportedInstance {
                        mesh,
                        transform: world * t,
                        node: Arc::clone(&path),
                        mesh_name: Arc::clone(&mesh_name),
                        gpu_instanced: gpu,
                    });
                }
            }
        }
        for child in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push((child, world, Some(Arc::clone(&path)), depth + 1));
        }
    }
    Ok(scene)
}

/// The glTF meshes (with triangles) of the `MSFT_lod` LOD nodes of `node`,
/// finest first (empty without the extension).
fn msft_lods(
    doc: &Document,
    node: &Node<'_>,
    meshes: &[Option<ImportedMesh>],
) -> Result<Vec<usize>, SimError> {
    let Some(ext) = node.extension_value("MSFT_lod") else {
        return Ok(Vec::new());
    };
    let ids = ext
        .get("ids")
        .and_then(|v| v.as_array())
        .ok_or_else(|| err(format!("node {}: MSFT_lod without ids", node.index())))?;
    let mut out = Vec::new();
    for id in ids {
        let n = id
            .as_u64()
            .and_then(|i| doc.nodes().nth(i as usize))
            .ok_or_else(|| {
                err(format!(
                    "node {}: MSFT_lod id {id} is no node",
                    node.index()
                ))
            })?;
        if let Some(m) = n.mesh() {
            if meshes[m.index()].is_some() {
                out.push(m.index());
            }
        }
    }
    Ok(out)
}

/// The per-instance transforms of `EXT_mesh_gpu_instancing` on `node`
/// (`None` without the extension).
fn gpu_instances<'a, 's, F>(
    doc: &'a Document,
    node: &Node<'a>,
    get: &F,
    buffers: &[Vec<u8>],
) -> Result<Option<Vec<Affine3A>>, SimError>
where
    F: Clone + Fn(::gltf::Buffer<'a>) -> Option<&'s [u8]>,
{
    let Some(ext) = node.extension_value("EXT_mesh_gpu_instancing") else {
        return Ok(None);
    };
    let attrs = ext
        .get("attributes")
        .and_then(|a| a.as_object())
        .ok_or_else(|| {
            err(format!(
                "node {}: EXT_mesh_gpu_instancing without attributes",
                node.index()
            ))
        })?;
    let accessor = |name: &str| -> Result<Option<::gltf::Accessor<'a>>, SimError> {
        match attrs.get(name) {
            None => Ok(None),
            Some(v) => {
                let i = v.as_u64().ok_or_else(|| {
                    err(format!(
                        "node {}: instancing attribute {name} is not an index",
                        node.index()
                    ))
                })?;
                doc.accessors().nth(i as usize).map(Some).ok_or_else(|| {
                    err(format!(
                        "node {}: instancing accessor {i} does not exist",
                        node.index()
                    ))
                })
            }
        }
    };
    let f32_only = |a: &::gltf::Accessor<'_>, name: &str| {
        if a.data_type() != ::gltf::accessor::DataType::F32 || a.normalized() {
            Err(err(format!(
                "node {}: instancing attribute {name} must be float (normalized integers are not read)",
                node.index()
            )))
        } else {
            Ok(())
        }
    };
    let read3 = |name: &str| -> Result<Option<Vec<[f32; 3]>>, SimError> {
        let Some(a) = accessor(name)? else {
            return Ok(None);
        };
        f32_only(&a, name)?;
        check_accessor(
            &a,
            buffers,
            Elements::Vec3F32,
            &format!("node {} instancing {name}", node.index()),
        )?;
        AccessorIter::<[f32; 3]>::new(a, get.clone())
            .map(|it| Some(it.collect()))
            .ok_or_else(|| {
                err(format!(
                    "node {}: cannot read instancing {name}",
                    node.index()
                ))
            })
    };
    let t = read3("TRANSLATION")?;
    let s = read3("SCALE")?;
    let r = match accessor("ROTATION")? {
        None => None,
        Some(a) => {
            f32_only(&a, "ROTATION")?;
            check_accessor(
                &a,
                buffers,
                Elements::Vec4F32,
                &format!("node {} instancing ROTATION", node.index()),
            )?;
            Some(
                AccessorIter::<[f32; 4]>::new(a, get.clone())
                    .map(|it| it.collect::<Vec<_>>())
                    .ok_or_else(|| {
                        err(format!(
                            "node {}: cannot read instancing ROTATION",
                            node.index()
                        ))
                    })?,
            )
        }
    };
    let n = [
        t.as_ref().map(Vec::len),
        s.as_ref().map(Vec::len),
        r.as_ref().map(Vec::len),
    ]
    .into_iter()
    .flatten()
    .max()
    .unwrap_or(0);
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let pick3 = |v: &Option<Vec<[f32; 3]>>, d: Vec3| -> Result<Vec3, SimError> {
            match v {
                None => Ok(d),
                Some(v) => v.get(i).map(|&x| Vec3::from(x)).ok_or_else(|| {
                    err(format!(
                        "node {}: instancing attributes differ in count",
                        node.index()
                    ))
                }),
            }
        };
        let tr = pick3(&t, Vec3::ZERO)?;
        let sc = pick3(&s, Vec3::ONE)?;
        let rot = match &r {
            None => Quat::IDENTITY,
            Some(v) => v
                .get(i)
                .map(|&q| Quat::from_array(q).normalize())
                .ok_or_else(|| {
                    err(format!(
                        "node {}: instancing attributes differ in count",
                        node.index()
                    ))
                })?,
        };
        let a = Affine3A::from_scale_rotation_translation(sc, rot, tr);
        if !a.is_finite() {
            return Err(err(format!(
                "node {}: instance {i} transform is not finite",
                node.index()
            )));
        }
        out.push(a);
    }
    Ok(Some(out))
}
