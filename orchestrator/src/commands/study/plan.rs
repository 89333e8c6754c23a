//! What a study will do, from its config folder and arguments: each training run with its
//! config and its folders, and Random's config. Reads the configs; runs nothing.

use std::path::{Path, PathBuf};

use farm::config::{Method, RunConfig};
use farm::rooms::{SceneId, SceneType, Split};

use super::args::StudyArgs;
use super::summary::{self, METHODS, StudyMethod};

/// One training run of the study.
#[derive(Clone, Debug)]
pub struct Run {
    pub method: StudyMethod,
    /// Trained, selected and tested in this type's rooms only (`--per-scene-type`).
    pub scene_type: Option<SceneType>,
    pub seed_index: u64,
    pub cfg: RunConfig,
    pub dir: PathBuf,
    pub config_path: PathBuf,
}

impl Run {
    /// The passes of its test evaluation: normal and blind (T4.6), and where the policy is shown
    /// the referencing gesture, another room's gesture (is where the arm points read?).
    pub fn test_modes(&self) -> &'static [&'static str] {
        if self.cfg.run.method.shows_referencing() {
            &["normal", "blind", "other_gesture"]
        } else {
            &["normal", "blind"]
        }
    }

    /// Frames one PPO update consumes.
    pub fn frames_per_update(&self, workers: usize) -> u64 {
        (self.cfg.ppo.rollout * workers * self.cfg.env.envs_per_worker) as u64
    }

    /// Updates a complete run has made.
    pub fn updates_needed(&self, workers: usize) -> u64 {
        (self.cfg.run.total_frames / self.frames_per_update(workers)).max(1)
    }

    pub fn latest_update(&self) -> u64 {
        farm::checkpoints::list(&farm::checkpoints::dir_of(&self.dir)).last().map_or(0, |(u, _)| *u)
    }

    pub fn trained(&self, workers: usize) -> bool {
        self.latest_update() >= self.updates_needed(workers)
    }

    /// The checkpoints val chooses from: the evenly spaced ones and the final one. A checkpoint
    /// written when the run was stopped part-way is not among them, so a study that was stopped
    /// and continued chooses from the same candidates as one that ran through.
    pub fn candidates(&self, workers: usize) -> Vec<PathBuf> {
        let (every, last) = (self.cfg.checkpoint.every_updates.max(1), self.updates_needed(workers));
        farm::checkpoints::list(&farm::checkpoints::dir_of(&self.dir))
            .into_iter()
            .filter(|(u, _)| u % every == 0 || *u >= last)
            .map(|(_, ckpt)| ckpt)
            .collect()
    }

    /// Where `ckpt`'s evaluation on val goes.
    pub fn select_dir(&self, ckpt: &Path) -> PathBuf {
        self.dir.join("select").join(ckpt.file_stem().unwrap_or_default())
    }

    /// Where the selected checkpoint's evaluations on test and on train go.
    pub fn test_dir(&self) -> PathBuf {
        self.dir.join("test")
    }

    pub fn train_dir(&self) -> PathBuf {
        self.dir.join("train")
    }

    /// The training's log, beside its folder.
    pub fn log(&self) -> PathBuf {
        self.dir.with_extension("log")
    }

    /// The rooms of `split` this run is evaluated in (`--scenes`; empty: all of them).
    pub fn rooms(&self, split: Split) -> Vec<String> {
        self.scene_type.map_or_else(Vec::new, |t| rooms_of(t, split))
    }

    /// The run's folder and record name, e.g. `both-seed1`.
    pub fn file_name(&self) -> String {
        self.dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
    }

    pub fn name(&self) -> String {
        let rooms = self.scene_type.map(|t| format!(" in {} rooms", t.name())).unwrap_or_default();
        format!("{}{rooms} seed {}", self.method.label, self.seed_index)
    }
}

/// Where a study keeps what it makes, under `--out` (the module doc draws the tree).
pub struct Layout<'a>(pub &'a Path);

impl Layout<'_> {
    /// A run's config (Random's too), as its children read it.
    pub fn config(&self, name: &str) -> PathBuf {
        self.0.join("configs").join(format!("{name}.toml"))
    }

    /// A training run's folder.
    pub fn run(&self, name: &str) -> PathBuf {
        self.0.join("runs").join(name)
    }

    /// Random's evaluation with seed `k`.
    pub fn random(&self, k: u64) -> PathBuf {
        self.0.join("random").join(format!("seed{k}"))
    }
}

fn rooms_of(t: SceneType, split: Split) -> Vec<String> {
    SceneId::of_split(split).filter(|s| s.scene_type == t).map(SceneId::name).collect()
}

/// The methods T4.3/T4.4 train once per scene type.
const PER_SCENE_TYPE: [&str; 3] = ["vis_sem", "referencing", "intervention"];

/// The runs of one method: one per seed, in every room and (`--per-scene-type`) per scene type.
fn runs_of(a: &StudyArgs, sm: StudyMethod, cfg: &RunConfig) -> Vec<Run> {
    let stem = sm.stem;
    let mut runs = Vec::new();
    let types: Vec<Option<SceneType>> = std::iter::once(None)
        .chain(SceneType::ALL.into_iter().map(Some).filter(|_| a.per_scene_type && PER_SCENE_TYPE.contains(&stem)))
        .collect();
    for t in types {
        for k in 1..=a.seeds {
            let mut c = cfg.clone();
            c.run.seed = cfg.run.seed + k - 1;
            c.run.total_frames = a.frames;
            // every training room (of the type), as §4.4.1 (the tiny configs pick 8 for
            // short single runs)
            c.run.scenes = t.map_or_else(Vec::new, |t| rooms_of(t, Split::Train));
            let name = match t {
                Some(t) => format!("{stem}-{}-seed{k}", t.name().to_ascii_lowercase()),
                None => format!("{stem}-seed{k}"),
            };
            let mut run = Run {
                method: sm,
                scene_type: t,
                seed_index: k,
                cfg: c,
                dir: Layout(&a.out).run(&name),
                config_path: Layout(&a.out).config(&name),
            };
            // keep every checkpoint, `checkpoints` of them evenly spaced (the final one is
            // written at the end of the run whatever the spacing)
            run.cfg.checkpoint.keep = 0;
            run.cfg.checkpoint.every_updates = (run.updates_needed(a.workers) / a.checkpoints).max(1);
            runs.push(run);
        }
    }
    runs
}

/// What the study will do, from the config folder: its learning runs and Random's seeds.
pub fn plan(a: &StudyArgs) -> anyhow::Result<(Vec<Run>, Option<RunConfig>)> {
    anyhow::ensure!(a.seeds > 0, "--seeds: at least one");
    anyhow::ensure!(a.frames > 0, "--frames: give a positive count");
    anyhow::ensure!(a.checkpoints > 0, "--checkpoints: at least one");
    for m in &a.methods {
        anyhow::ensure!(
            summary::method(m).is_some(),
            "--methods: `{m}` is not one of {}",
            METHODS.map(|m| m.stem).join(", ")
        );
    }
    let mut runs = Vec::new();
    let mut random = None;
    // T4.2's order, or the order asked for (the first methods of a long study finish first)
    let order: Vec<StudyMethod> = match a.methods.is_empty() {
        true => METHODS.to_vec(),
        false => a.methods.iter().filter_map(|m| summary::method(m)).collect(),
    };
    for sm in order {
        let stem = sm.stem;
        let path = a.configs.join(format!("{stem}.toml"));
        if !path.is_file() {
            anyhow::ensure!(a.methods.is_empty(), "--methods {stem}: no {}", path.display());
            continue;
        }
        let mut cfg = RunConfig::load(&path)?.with_overrides(&a.set)?;
        if let Some(d) = &a.dataset {
            cfg.run.dataset = d.clone();
        }
        anyhow::ensure!(
            cfg.run.method == sm.method,
            "{}: run.method is {:?}, the file name says {stem}",
            path.display(),
            cfg.run.method
        );
        if sm.method == Method::Random {
            random = Some(cfg);
            continue;
        }
        anyhow::ensure!(
            (cfg.model.rgb, cfg.model.depth) == (sm.rgb, sm.depth),
            "{}: model.rgb = {}, model.depth = {}; {stem} needs {} and {}",
            path.display(),
            cfg.model.rgb,
            cfg.model.depth,
            sm.rgb,
            sm.depth
        );
        runs.extend(runs_of(a, sm, &cfg));
    }
    // seed by seed: a study stopped part-way has every method at its first seeds (stable: the
    // methods keep T4.2's order within a seed)
    runs.sort_by_key(|r| r.seed_index);
    anyhow::ensure!(
        !runs.is_empty() || random.is_some(),
        "{}: no config named after a method of T4.2 or T4.7 ({}.toml)",
        a.configs.display(),
        METHODS.map(|m| m.stem).join(".toml, ")
    );
    Ok((runs, random))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(dir: &Path) -> StudyArgs {
        StudyArgs {
            configs: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/tiny"),
            seeds: 2,
            frames: 40_960,
            out: dir.to_path_buf(),
            methods: vec![],
            per_scene_type: false,
            workers: 4,
            checkpoints: 5,
            val_programs: 100,
            test_programs: 100,
            dataset: None,
            publish: None,
            set: Vec::new(),
            parallel: 1,
        }
    }

    #[test]
    fn the_plan_has_every_learning_method_per_seed_and_random_apart() {
        let dir = tempfile::tempdir().unwrap();
        let (runs, random) = plan(&args(dir.path())).unwrap();
        assert_eq!(runs.len(), 7 * 2, "T4.2's five learning methods and T4.7's two variants");
        assert!(random.is_some());
        let order: Vec<(&str, u64)> = runs.iter().map(|r| (r.method.stem, r.seed_index)).collect();
        assert_eq!(&order[..2], [("vision_only", 1), ("vis_sem", 1)], "seed by seed, in T4.2's order");
        let mut asked = args(dir.path());
        asked.methods = vec!["both".into(), "vis_sem".into()];
        let (runs2, random) = plan(&asked).unwrap();
        let order: Vec<(&str, u64)> = runs2.iter().map(|r| (r.method.stem, r.seed_index)).collect();
        assert_eq!(order, [("both", 1), ("vis_sem", 1), ("both", 2), ("vis_sem", 2)], "in the order asked for");
        assert!(random.is_none());
        let both2 = runs.iter().find(|r| r.method.stem == "both" && r.seed_index == 2).unwrap();
        assert_eq!(both2.cfg.run.seed, 2, "seeds 1 and 2 from the config's seed 1");
        assert_eq!(both2.cfg.run.total_frames, 40_960);
        // 4 workers × 8 envs × 128 steps = 4,096 frames an update: 10 updates, one checkpoint in 2
        assert_eq!(
            (both2.updates_needed(4), both2.cfg.checkpoint.every_updates, both2.cfg.checkpoint.keep),
            (10, 2, 0)
        );
        assert!(both2.dir.ends_with("runs/both-seed2"));
        assert!(both2.cfg.run.scenes.is_empty(), "the study trains in all 80 training rooms");
    }

    #[test]
    fn val_chooses_from_the_spaced_and_final_checkpoints_not_one_written_at_a_stop() {
        let dir = tempfile::tempdir().unwrap();
        let (runs, _) = plan(&args(dir.path())).unwrap();
        let run = &runs[0];
        // 10 updates, one checkpoint in 2; the run was stopped at update 3 and continued
        let ckpts = farm::checkpoints::dir_of(&run.dir);
        std::fs::create_dir_all(&ckpts).unwrap();
        for u in [2, 3, 4, 6, 8, 10] {
            std::fs::write(farm::checkpoints::path(&ckpts, u), b"").unwrap();
        }
        let chosen_from: Vec<u64> =
            run.candidates(4).iter().map(|p| farm::checkpoints::update_of(p).unwrap()).collect();
        assert_eq!(chosen_from, [2, 4, 6, 8, 10], "as a study that ran through");
    }

    #[test]
    fn t47_variants_and_per_scene_type_runs_are_planned_apart() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path());
        a.seeds = 1;
        a.per_scene_type = true;
        let (runs, _) = plan(&a).unwrap();
        // 7 models in every room (T4.2's five, T4.7's two), 3 methods × 4 scene types
        assert_eq!(runs.len(), 7 + 12, "{:?}", runs.iter().map(|r| r.dir.clone()).collect::<Vec<_>>());
        let rgb = runs.iter().find(|r| r.method.stem == "rgb_sem_both").unwrap();
        assert!(rgb.cfg.model.rgb && !rgb.cfg.model.depth && rgb.cfg.run.method == Method::Both);
        let bath =
            runs.iter().find(|r| r.method.stem == "intervention" && r.scene_type == Some(SceneType::Bathroom)).unwrap();
        assert!(bath.dir.ends_with("runs/intervention-bathroom-seed1"));
        assert_eq!(bath.cfg.run.scenes.len(), 20);
        assert!(bath.cfg.run.scenes.iter().all(|s| SceneId::parse(s).unwrap().scene_type == SceneType::Bathroom));
        assert_eq!(
            bath.rooms(Split::Test),
            ["FloorPlan426", "FloorPlan427", "FloorPlan428", "FloorPlan429", "FloorPlan430"]
        );
        assert!(runs.iter().all(|r| r.scene_type.is_none() || PER_SCENE_TYPE.contains(&r.method.stem)));
        // a variant whose inputs contradict its name
        std::fs::create_dir_all(dir.path().join("c")).unwrap();
        let both = std::fs::read_to_string(a.configs.join("both.toml")).unwrap();
        std::fs::write(dir.path().join("c/depth_sem_both.toml"), both).unwrap();
        a.configs = dir.path().join("c");
        let e = plan(&a).unwrap_err().to_string();
        assert!(e.contains("depth_sem_both.toml") && e.contains("model.rgb = true"), "{e}");
    }

    #[test]
    fn unknown_or_missing_methods_are_one_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = args(dir.path());
        a.methods = vec!["bothh".into()];
        assert!(plan(&a).unwrap_err().to_string().contains("`bothh`"));
        a.configs = dir.path().to_path_buf();
        a.methods = vec![];
        let e = plan(&a).unwrap_err().to_string();
        assert!(e.contains("no config named after a method"), "{e}");
    }
}
