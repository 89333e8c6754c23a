//! `gesthor._gesthor`: the native half of the `gesthor` Python package. One [`Pool`] is one
//! worker's `EnvPool` (the simulator, its renderer, E environments) in the Python process,
//! writing observations into a buffer it owns, laid out as the farm's observation payload
//! (`shm_schema`). Python views that buffer with numpy without copying (`gesthor/vector.py`)
//! and steps the pool with the interpreter's lock released.

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use farm::config::RunConfig;
use shm_schema::{EnvRecord, EpisodeSummary, ObsLayout};
use worker::env::{EnvPool, PoolSpec, ProgramSource};

/// E environments of one configuration, stepped together.
#[pyclass(module = "gesthor._gesthor")]
struct Pool {
    pool: EnvPool,
    layout: ObsLayout,
    payload: Vec<u8>,
    config: RunConfig,
}

fn runtime(e: anyhow::Error) -> PyErr {
    PyRuntimeError::new_err(format!("{e:#}"))
}

#[pymethods]
impl Pool {
    /// `config_toml`: a run configuration (the text of a config file), `overrides`: `KEY=VALUE`
    /// as `orchestrator --set` takes them, `programs`: run exactly these programs of the split
    /// in order instead of drawing them from the seeded stream.
    #[new]
    #[pyo3(signature = (config_toml, overrides, source = "(gesthor config)", programs = None))]
    fn new(config_toml: &str, overrides: Vec<String>, source: &str, programs: Option<Vec<u64>>) -> PyResult<Pool> {
        let config = RunConfig::from_toml(config_toml, source)
            .and_then(|c| c.with_overrides(&overrides))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let n = config.env.envs_per_worker;
        if n == 0 || n > shm_schema::MAX_ENVS {
            return Err(PyValueError::new_err(format!("num_envs: {n} is not in 1..={}", shm_schema::MAX_ENVS)));
        }
        let spec = PoolSpec {
            worker_id: 0,
            generation: 0,
            programs: programs.map_or(ProgramSource::Sample, ProgramSource::Sequence),
            expert_hints: false,
        };
        let pool = EnvPool::new(&config, spec).map_err(runtime)?;
        let layout = pool.layout();
        Ok(Pool { pool, payload: vec![0; layout.total_len as usize], layout, config })
    }

    /// Starts every env; the buffer then holds their first observations.
    fn reset(&mut self, py: Python<'_>) -> PyResult<()> {
        let (pool, payload) = (&mut self.pool, &mut self.payload);
        py.detach(|| pool.reset(payload)).map_err(runtime)
    }

    /// One action per env (bytes of 0 MoveAhead, 1 RotateLeft, 2 RotateRight, 3 Stop); the
    /// buffer then holds the next observations (the episode-end protocol of the farm: an env
    /// whose last observation ended its episode ignores its action and starts the next one).
    fn step(&mut self, py: Python<'_>, actions: Vec<u8>) -> PyResult<()> {
        if actions.len() != self.pool.num_envs() {
            return Err(PyValueError::new_err(format!("{} actions for {} envs", actions.len(), self.pool.num_envs())));
        }
        if let Some(a) = actions.iter().find(|&&a| a > shm_schema::action::STOP) {
            return Err(PyValueError::new_err(format!("action {a} is not one of 0, 1, 2, 3")));
        }
        let (pool, payload) = (&mut self.pool, &mut self.payload);
        py.detach(|| pool.step(&actions, payload)).map_err(runtime)
    }

    /// Address and length of the observation buffer: fixed for the pool's life (Python's
    /// numpy views hold a reference to the pool).
    fn buffer(&self) -> (usize, usize) {
        (self.payload.as_ptr() as usize, self.payload.len())
    }

    /// Byte offsets and strides of the buffer's sections.
    fn layout(&self) -> std::collections::BTreeMap<&'static str, u64> {
        let l = &self.layout;
        [
            ("records_offset", l.records_offset),
            ("record_size", std::mem::size_of::<EnvRecord>() as u64),
            ("rgb_offset", l.rgb_offset),
            ("rgb_stride", l.rgb_stride),
            ("depth_offset", l.depth_offset),
            ("depth_stride", l.depth_stride),
            ("gesture_offset", l.gesture_offset),
            ("gesture_stride", l.gesture_stride),
            ("total_len", l.total_len),
        ]
        .into_iter()
        .collect()
    }

    #[getter]
    fn num_envs(&self) -> usize {
        self.pool.num_envs()
    }

    /// The effective configuration, as TOML.
    #[getter]
    fn config(&self) -> String {
        self.config.to_toml()
    }

    /// Every env has run out of its given programs.
    fn finished(&self) -> bool {
        self.pool.finished()
    }

    /// The GPU (or CPU) adapter the renderer runs on.
    fn renderer(&self) -> String {
        self.pool.renderer_info()
    }
}

/// The fields of an env's record as (name, numpy format, byte offset): a numpy structured
/// dtype views the records without copying.
#[pyfunction]
fn record_fields() -> Vec<(&'static str, &'static str, usize)> {
    use std::mem::offset_of;
    let s = offset_of!(EnvRecord, summary);
    vec![
        ("env_step", "<u8", offset_of!(EnvRecord, env_step)),
        ("episode", "<u8", offset_of!(EnvRecord, episode)),
        ("program", "<u8", offset_of!(EnvRecord, program)),
        ("episode_step", "<u4", offset_of!(EnvRecord, episode_step)),
        ("last_action", "<u4", offset_of!(EnvRecord, last_action)),
        ("reward", "<f4", offset_of!(EnvRecord, reward)),
        ("terminated", "u1", offset_of!(EnvRecord, terminated)),
        ("truncated", "u1", offset_of!(EnvRecord, truncated)),
        ("episode_start", "u1", offset_of!(EnvRecord, episode_start)),
        ("success", "u1", offset_of!(EnvRecord, success)),
        ("collided", "u1", offset_of!(EnvRecord, collided)),
        ("gesture_kind", "u1", offset_of!(EnvRecord, gesture_kind)),
        ("gesture_index", "u1", offset_of!(EnvRecord, gesture_index)),
        ("idle", "u1", offset_of!(EnvRecord, idle)),
        ("stops", "<u4", offset_of!(EnvRecord, stops)),
        ("target_category", "<u4", offset_of!(EnvRecord, target_category)),
        ("target_instances", "<u4", offset_of!(EnvRecord, target_instances)),
        ("visible_pixels", "<u4", offset_of!(EnvRecord, visible_pixels)),
        ("robot", "(3,)<f4", offset_of!(EnvRecord, robot)),
        ("person_rel", "(3,)<f4", offset_of!(EnvRecord, person_rel)),
        ("distance", "<f4", offset_of!(EnvRecord, distance)),
        ("geodesic", "<f4", offset_of!(EnvRecord, geodesic)),
        ("episode_steps", "<u4", s + offset_of!(EpisodeSummary, steps)),
        ("episode_success", "<u4", s + offset_of!(EpisodeSummary, success)),
        ("episode_collisions", "<u4", s + offset_of!(EpisodeSummary, collisions)),
        ("episode_stops", "<u4", s + offset_of!(EpisodeSummary, num_stops)),
        ("path_length", "<f4", s + offset_of!(EpisodeSummary, path_length)),
        ("shortest_path", "<f4", s + offset_of!(EpisodeSummary, shortest_path)),
        ("final_distance", "<f4", s + offset_of!(EpisodeSummary, final_distance)),
        ("episode_return", "<f4", s + offset_of!(EpisodeSummary, total_reward)),
        ("intervention_steps", "<u4", s + offset_of!(EpisodeSummary, intervention_steps)),
    ]
}

#[pymodule]
fn _gesthor(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Pool>()?;
    m.add_function(wrap_pyfunction!(record_fields, m)?)?;
    m.add("GESTURE_FRAMES", shm_schema::GESTURE_FRAMES)?;
    m.add("GESTURE_DIMS", shm_schema::GESTURE_DIMS)?;
    m.add("TARGET_CATEGORIES", shm_schema::TARGET_CATEGORIES)?;
    Ok(())
}
