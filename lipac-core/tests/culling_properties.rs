//! Property tests of the per-frame loop ([`lipac_core::culling::Culling`]):
//! random scenes (shared and unique BLASes, random boxes over a 4 x 4 grid),
//! random hit sequences derived from a per-instance importance and a
//! per-frame factor, random per-frame budgets, small command buffers (to
//! force overflow), read-back latency 1–3, instance churn (remove /
//! re-register, exercising slot quarantine and dead-slot commands), latency
//! mitigation with a moving camera, and BLAS builds that finish frames later.
//!
//! The test side plays the BLAS manager: it hands out unique addresses,
//! remembers which instance holds which, and fails on a double acquire, a
//! release of something not held, or a cancel of a build never requested.

use std::collections::{HashMap, HashSet};

use glam::camera::rh::{proj, view};
use glam::{Affine3A, Vec3};
use lipac_core::culling::{BlasAction, CommandEvent, Culling, CullingConfig, ReadbackRing};
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::{InstanceDesc, InstanceFlags, MeshId};
use lipac_core::latency::{ActivationHeuristic, Frustum};
use lipac_core::layout::{InstanceState, TlasInstance};
use lipac_core::math::Aabb;
use lipac_core::registry::InstanceHandle;
use lipac_core::thresholds::Thresholds;
use proptest::prelude::*;

const CUBE: u64 = 0xC0BE;
const IMPORTANCE: [u32; 5] = [0, 60, 400, 1200, 2500];

#[derive(Clone, Debug)]
struct Spec {
    x: f32,
    z: f32,
    size: f32,
    height: f32,
    unique: bool,
    mesh: u32,
    importance: u32,
}

impl Spec {
    fn desc(&self) -> InstanceDesc {
        let aabb = Aabb::new(
            Vec3::new(self.x - self.size, 0.0, self.z - self.size),
            Vec3::new(self.x + self.size, self.height, self.z + self.size),
        );
        let mut d = InstanceDesc::new(
            MeshId(self.mesh),
            Affine3A::from_translation(Vec3::new(self.x, 0.0, self.z)),
            aabb,
        );
        if self.unique {
            d.flags = InstanceFlags::UNIQUE_BLAS;
        }
        d
    }
}

#[derive(Clone, Debug)]
struct FrameParams {
    /// Hits this frame = importance · factor.
    factor: u32,
    /// `None` = unlimited.
    budget: Option<usize>,
    camera: usize,
    /// Identities whose liveness toggles at the start of the frame.
    churn: Vec<usize>,
}

#[derive(Clone, Debug)]
struct Params {
    specs: Vec<Spec>,
    frames: Vec<FrameParams>,
    capacity: u32,
    latency: u32,
    mitigation: bool,
    seed: u64,
}

fn spec() -> impl Strategy<Value = Spec> {
    (
        0.5f32..63.5,
        0.5f32..63.5,
        0.1f32..4.0,
        0.0f32..12.0,
        any::<bool>(),
        0u32..4,
        0usize..IMPORTANCE.len(),
    )
        .prop_map(|(x, z, size, height, unique, mesh, i)| Spec {
            x,
            z,
            size,
            height,
            unique,
            mesh,
            importance: IMPORTANCE[i],
        })
}

fn params() -> impl Strategy<Value = Params> {
    (
        prop::collection::vec(spec(), 1..24),
        1u32..6,
        1u32..=3,
        any::<bool>(),
        any::<u64>(),
    )
        .prop_flat_map(|(specs, capacity, latency, mitigation, seed)| {
            let n = specs.len();
            let frame = (
                0u32..3,
                prop::option::weighted(0.7, 0usize..4),
                0usize..3,
                prop::collection::vec(0..n, 0..2),
            )
                .prop_map(|(factor, budget, camera, churn)| FrameParams {
                    factor,
                    budget,
                    camera,
                    churn,
                });
            prop::collection::vec(frame, 10..40).prop_map(move |frames| Params {
                specs: specs.clone(),
                frames,
                capacity,
                latency,
                mitigation,
                seed,
            })
        })
}

fn cameras() -> [(Vec3, Frustum); 3] {
    let make = |camera: Vec3, dir: Vec3, fov: f32| {
        let v = view::look_to_mat4(camera, dir, Vec3::NEG_Z);
        let p = proj::vulkan::perspective(fov.to_radians(), 1.0, 0.1, 500.0);
        (camera, Frustum::from_view_projection(p * v).unwrap())
    };
    [
        make(Vec3::new(32.0, 40.0, 32.0), Vec3::Y, 60.0), // sees nothing
        make(Vec3::new(32.0, 40.0, 32.0), Vec3::NEG_Y, 100.0), // sees all
        make(Vec3::new(12.0, 20.0, 12.0), Vec3::NEG_Y, 60.0), // one corner
    ]
}

fn mix(a: u64, b: u64) -> u64 {
    let mut x = a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^ (x >> 29)
}

/// The BLAS manager played by the test.
#[derive(Default)]
struct Model {
    seed: u64,
    frame: u64,
    next_addr: u64,
    /// identity -> address held.
    held: HashMap<usize, u64>,
    /// identity -> frame its pending build finishes.
    building: HashMap<usize, u64>,
    released: HashSet<u64>,
    errors: Vec<String>,
}

impl Model {
    /// Acquire for `id`: ready now (Some) or built after 1–3 frames (None).
    fn acquire(&mut self, id: usize) -> Option<u64> {
        if self.held.contains_key(&id) || self.building.contains_key(&id) {
            self.errors.push(format!(
                "frame {}: second BLAS for instance {id}",
                self.frame
            ));
        }
        let r = mix(self.seed, (id as u64) << 32 | self.frame);
        if r % 3 == 0 {
            self.building.insert(id, self.frame + 1 + (r >> 8) % 3);
            None
        } else {
            Some(self.grant(id))
        }
    }

    fn grant(&mut self, id: usize) -> u64 {
        self.next_addr += 1;
        let addr = 0x10_0000 + self.next_addr;
        self.held.insert(id, addr);
        addr
    }

    fn release(&mut self, id: usize, blas: u64) {
        if self.held.get(&id) != Some(&blas) {
            self.errors.push(format!(
                "frame {}: release of {blas:#x} by {id}, which holds {:?}",
                self.frame,
                self.held.get(&id)
            ));
        }
        if !self.released.insert(blas) {
            self.errors
                .push(format!("frame {}: {blas:#x} released twice", self.frame));
        }
        self.held.remove(&id);
    }

    fn cancel(&mut self, id: usize) {
        if self.building.remove(&id).is_none() {
            self.errors.push(format!(
                "frame {}: cancel of a build {id} never requested",
                self.frame
            ));
        }
    }
}

struct Sim {
    culling: Culling,
    ring: ReadbackRing,
    specs: Vec<Spec>,
    handles: Vec<Option<InstanceHandle>>,
    ids: HashMap<InstanceHandle, usize>,
    model: Model,
    cameras: [(Vec3, Frustum); 3],
    tlas: Vec<TlasInstance>,
    /// Per frame: TLAS size and the active bits of all hitboxes.
    trace: Vec<(usize, Vec<bool>)>,
    frame: u64,
}

impl Sim {
    fn new(p: &Params, order: &[usize], unlimited: bool) -> Self {
        let grid = HitboxGrid::new(GridConfig {
            min: [0.0, 0.0],
            max: [64.0, 64.0],
            cell_size: 16.0,
        })
        .unwrap();
        let mut cfg = CullingConfig::new(CUBE);
        cfg.thresholds = Thresholds {
            n_a: 2,
            n_d: 8,
            ..Thresholds::paper()
        };
        cfg.command_capacity = if unlimited { 1 << 16 } else { p.capacity };
        cfg.readback_latency = p.latency;
        cfg.latency_mitigation = p.mitigation.then_some(ActivationHeuristic {
            max_distance: 30.0,
            min_projected_size: 0.05,
            surround_radius: 0.0,
        });
        let mut sim = Sim {
            culling: Culling::new(grid, cfg).unwrap(),
            ring: ReadbackRing::new(p.latency).unwrap(),
            specs: p.specs.clone(),
            handles: vec![None; p.specs.len()],
            ids: HashMap::new(),
            model: Model {
                seed: p.seed,
                ..Model::default()
            },
            cameras: cameras(),
            tlas: Vec::new(),
            trace: Vec::new(),
            frame: 0,
        };
        for &id in order {
            sim.register(id);
        }
        sim
    }

    fn register(&mut self, id: usize) {
        let h = self.culling.register(self.specs[id].desc()).unwrap();
        self.handles[id] = Some(h);
        self.ids.insert(h, id);
    }

    fn toggle(&mut self, id: usize) {
        match self.handles[id].take() {
            None => self.register(id),
            Some(h) => {
                let r = self.culling.remove(h).unwrap();
                self.ids.remove(&h);
                if r.instance.blas != 0 {
                    self.model.release(id, r.instance.blas);
                }
                if r.build_was_pending {
                    self.model.cancel(id);
                }
            }
        }
    }

    fn hits(&self, id: usize, factor: u32) -> u32 {
        self.specs[id].importance * factor
    }

    /// One frame; returns the number of commands the feedback requested.
    fn step(&mut self, fp: &FrameParams, budget_unlimited: bool) -> Result<u32, TestCaseError> {
        let frame = self.frame;
        self.model.frame = frame;
        for &id in &fp.churn {
            self.toggle(id);
        }
        self.culling.begin_frame(frame).unwrap();

        // Finished builds.
        let done: Vec<usize> = self
            .model
            .building
            .iter()
            .filter(|&(_, &at)| at <= frame)
            .map(|(&id, _)| id)
            .collect();
        for id in done {
            self.model.building.remove(&id);
            let h = self.handles[id].expect("a removed instance's build was cancelled");
            prop_assert!(self.culling.awaiting_blas(h).unwrap());
            let addr = self.model.grant(id);
            prop_assert_eq!(self.culling.set_blas(h, addr).unwrap(), 0);
        }

        // Latency mitigation.
        let (camera, frustum) = self.cameras[fp.camera];
        let out = self.culling.mitigate_latency(camera, &frustum).unwrap();
        for r in out.requests {
            let id = self.ids[&r.handle];
            if let Some(addr) = self.model.acquire(id) {
                prop_assert_eq!(self.culling.set_blas(r.handle, addr).unwrap(), 0);
            }
        }

        // Commands.
        while let Some(r) = self.ring.pop_ready(frame) {
            let s = self.culling.ingest_readback(r.frame, r.counter, &r.words);
            prop_assert_eq!(s.rejected, 0);
        }
        let budget = if budget_unlimited {
            usize::MAX
        } else {
            fp.budget.unwrap_or(usize::MAX)
        };
        let mut events: Vec<CommandEvent> = Vec::new();
        let st = self.culling.process_commands(budget, &mut events);
        for e in events {
            let id = self.ids[&e.handle];
            match e.action {
                BlasAction::Acquire => {
                    if let Some(addr) = self.model.acquire(id) {
                        prop_assert_eq!(self.culling.set_blas(e.handle, addr).unwrap(), 0);
                    }
                }
                BlasAction::Release { blas } => self.model.release(id, blas),
                BlasAction::CancelBuild => self.model.cancel(id),
            }
        }
        prop_assert_eq!(st.dead, 0, "dead commands are dropped at ingest");
        prop_assert!(self.model.errors.is_empty(), "{:?}", self.model.errors);

        // Algorithm 1 and the TLAS properties.
        let mut tlas = std::mem::take(&mut self.tlas);
        self.culling.assemble(&mut tlas).unwrap();
        self.check_tlas(&tlas)?;

        // Trace.
        let cfg = *self.culling.config();
        let mut box_hits = vec![0u32; self.culling.hitboxes().len()];
        for (id, h) in self.handles.iter().enumerate() {
            if let Some(h) = h {
                let hb = self.culling.registry().record(*h).unwrap().hitbox;
                box_hits[hb as usize] += self.hits(id, fp.factor);
            }
        }
        for r in &tlas {
            let i = r.custom_index();
            if r.acceleration_structure_reference == CUBE
                && r.sbt_offset() == cfg.assembly.hitbox_sbt_offset
            {
                self.culling.hitboxes_mut()[i as usize].add_hits(box_hits[i as usize]);
            } else {
                let id = self.ids[&self.culling.registry().handle_at(i).unwrap()];
                let hits = self.hits(id, fp.factor);
                self.culling.instance_hits_mut()[i as usize] = hits;
            }
        }
        self.trace.push((
            tlas.len(),
            self.culling
                .hitboxes()
                .iter()
                .map(|h| h.is_active())
                .collect(),
        ));
        self.tlas = tlas;

        // Algorithm 2 and the read-back.
        self.culling.process_feedback().unwrap();
        let rb = self.culling.take_commands().unwrap();
        let requested = rb.counter;
        self.ring.push(rb).unwrap();
        self.check_no_command_lost()?;
        self.frame += 1;
        Ok(requested)
    }

    /// Properties 1 and 2 on this frame's TLAS.
    fn check_tlas(&self, tlas: &[TlasInstance]) -> Result<(), TestCaseError> {
        let reg = self.culling.registry();
        let hitboxes = self.culling.hitboxes();
        let cfg = self.culling.config().assembly;
        let mut own = 0;
        for r in tlas {
            let i = r.custom_index();
            if r.acceleration_structure_reference != CUBE {
                own += 1;
                let h = reg.handle_at(i);
                prop_assert!(h.is_some(), "TLAS record for dead slot {}", i);
                let rec = reg.record_at(i).unwrap();
                prop_assert_eq!(rec.state(), InstanceState::Active);
                prop_assert_ne!(rec.blas, 0);
                prop_assert_eq!(rec.blas, r.acceleration_structure_reference);
                let id = self.ids[&h.unwrap()];
                prop_assert_eq!(self.model.held.get(&id), Some(&rec.blas));
                prop_assert!(
                    hitboxes[rec.hitbox as usize].is_active(),
                    "instance of an inactive hitbox in the TLAS"
                );
            } else if r.sbt_offset() == cfg.omitted_box_sbt_offset {
                prop_assert!(reg.handle_at(i).is_some());
                let rec = reg.record_at(i).unwrap();
                prop_assert_eq!(rec.state(), InstanceState::Omitted);
                prop_assert!(
                    hitboxes[rec.hitbox as usize].is_active(),
                    "omitted box of an inactive hitbox in the TLAS"
                );
            } else {
                prop_assert_eq!(r.sbt_offset(), cfg.hitbox_sbt_offset);
                prop_assert!(!hitboxes[i as usize].is_active());
                prop_assert!(
                    reg.iter()
                        .any(|(_, s)| reg.record_at(s).unwrap().hitbox == i),
                    "box of hitbox {} without instances",
                    i
                );
            }
        }
        // Completeness: every active instance with a BLAS in an active
        // hitbox is in the TLAS.
        let expected = reg
            .iter()
            .filter(|&(_, s)| {
                let rec = reg.record_at(s).unwrap();
                rec.state() == InstanceState::Active
                    && rec.blas != 0
                    && hitboxes[rec.hitbox as usize].is_active()
            })
            .count();
        prop_assert_eq!(own, expected);
        Ok(())
    }

    /// Property 3, every frame: an instance whose BLAS disagrees with its
    /// state has a command pending or in flight, and the model agrees with
    /// the records.
    fn check_no_command_lost(&self) -> Result<(), TestCaseError> {
        let reg = self.culling.registry();
        let in_flight: HashSet<u32> = self
            .ring
            .iter()
            .flat_map(|r| r.words.iter().map(|w| w & 0x00FF_FFFF))
            .collect();
        for (id, h) in self.handles.iter().enumerate() {
            let Some(h) = *h else { continue };
            let rec = reg.record(h).unwrap();
            let slot = reg.slot(h).unwrap();
            prop_assert_eq!(
                self.model.held.get(&id).copied().unwrap_or(0),
                rec.blas,
                "model and record disagree for {}",
                id
            );
            prop_assert_eq!(
                self.model.building.contains_key(&id),
                self.culling.awaiting_blas(h).unwrap()
            );
            let wants = rec.state() == InstanceState::Active;
            let has = rec.blas != 0 || self.culling.awaiting_blas(h).unwrap();
            if wants != has {
                prop_assert!(
                    self.culling.pending_command(slot).is_some() || in_flight.contains(&slot),
                    "instance {} (slot {}) {:?} with BLAS {:#x} has no command pending",
                    id,
                    slot,
                    rec.state(),
                    rec.blas
                );
            }
        }
        Ok(())
    }

    /// Runs quiet frames (constant hits, fixed camera, unlimited budget)
    /// until nothing is pending or in flight for `latency + 2` frames.
    fn settle(&mut self, camera: usize) -> Result<(), TestCaseError> {
        let quiet = FrameParams {
            factor: 1,
            budget: None,
            camera,
            churn: Vec::new(),
        };
        let mut calm = 0;
        for _ in 0..400 {
            let requested = self.step(&quiet, true)?;
            let idle = requested == 0
                && self.culling.pending_commands() == 0
                && self.ring.iter().all(|r| r.counter == 0)
                && self.model.building.is_empty();
            calm = if idle { calm + 1 } else { 0 };
            if calm > self.ring.latency() as usize + 1 {
                return Ok(());
            }
        }
        Err(TestCaseError::fail("the loop did not settle in 400 frames"))
    }

    /// identity -> (state, holds a BLAS), for live instances.
    fn outcome(&self) -> Vec<Option<(InstanceState, bool)>> {
        self.handles
            .iter()
            .map(|h| {
                h.map(|h| {
                    let rec = self.culling.registry().record(h).unwrap();
                    (rec.state(), rec.blas != 0)
                })
            })
            .collect()
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Properties 1–3 under overflow, budgets, latency, churn and latency
    /// mitigation; at the end, after the loop settles, the instances holding
    /// a BLAS are exactly the active ones.
    #[test]
    fn loop_keeps_tlas_and_blas_consistent(p in params()) {
        let order: Vec<usize> = (0..p.specs.len()).collect();
        let mut sim = Sim::new(&p, &order, false);
        for fp in &p.frames {
            sim.step(fp, false)?;
        }
        let camera = p.frames.last().map_or(0, |f| f.camera);
        sim.settle(camera)?;
        let reg = sim.culling.registry();
        let active: HashSet<usize> = sim.handles.iter().enumerate()
            .filter_map(|(id, h)| h.filter(|&h| reg.state(h).unwrap() == InstanceState::Active).map(|_| id))
            .collect();
        let holding: HashSet<usize> = sim.model.held.keys().copied().collect();
        prop_assert_eq!(holding, active);
        // Every address ever granted is either held or released exactly once.
        prop_assert_eq!(
            sim.model.held.len() + sim.model.released.len(),
            sim.model.next_addr as usize
        );
    }

    /// Property 4: the outcome does not depend on the registration order.
    /// Command capacity and budget are unlimited here: with limits, *which*
    /// transitions fit into this frame's buffer or budget depends on slot
    /// order (GPU threads race for the atomic counter; ties in priority are
    /// broken by slot), so per-frame results legitimately differ, and only
    /// the eventual agreement of BLASes and states (property 3) is
    /// order-independent.
    #[test]
    fn outcome_is_independent_of_registration_order(p in params(), rot in any::<prop::sample::Index>()) {
        let n = p.specs.len();
        let forward: Vec<usize> = (0..n).collect();
        let k = rot.index(n);
        let permuted: Vec<usize> = (0..n).rev().map(|i| (i + k) % n).collect();
        let mut a = Sim::new(&p, &forward, true);
        let mut b = Sim::new(&p, &permuted, true);
        for fp in &p.frames {
            a.step(fp, true)?;
            b.step(fp, true)?;
            prop_assert_eq!(&a.trace, &b.trace, "frame {}", a.frame - 1);
            prop_assert_eq!(a.outcome(), b.outcome());
        }
        let held = |s: &Sim| s.model.held.keys().copied().collect::<HashSet<_>>();
        prop_assert_eq!(held(&a), held(&b));
    }
}
