//! The rooms a pool's envs run in, prepared once per room and shared.

use std::collections::HashMap;
use std::sync::Arc;

use crate::dataset::Dataset;
use crate::dataset::build::RoomContext;
use crate::scene::SceneId;
use farm::config::RunConfig;

/// Rooms shared by the envs of a pool: scene, reachable grid, targets' success regions.
pub struct Rooms {
    dataset: Arc<Dataset>,
    cache: HashMap<SceneId, Arc<RoomContext>>,
    cfg: RunConfig,
}

impl Rooms {
    pub fn new(dataset: Arc<Dataset>, cfg: &RunConfig) -> Rooms {
        Rooms { dataset, cache: HashMap::new(), cfg: cfg.clone() }
    }

    pub fn get(&mut self, id: SceneId) -> anyhow::Result<Arc<RoomContext>> {
        if let Some(r) = self.cache.get(&id) {
            return Ok(r.clone());
        }
        let scene = self.dataset.scene(id)?;
        let ctx = Arc::new(RoomContext::new(id, scene, &self.cfg.env, self.cfg.task.success_distance));
        self.cache.insert(id, ctx.clone());
        Ok(ctx)
    }
}
