//! `ppo.overlap_update`: the update of a full rollout runs on a thread, on a copy of the network,
//! while the agent collects the next rollout with the weights before it (a policy lag of one
//! update). A full rollout is queued at the step that completes it and handed to the thread at
//! the next step, with the trainer's weights, Adam moments and minibatch order as they are then;
//! they come back into the trainer when the next rollout is full. Between steps the trainer's
//! state is always that after its last joined update, so a checkpoint written at any step is
//! consistent (the rollouts queued or in flight are not in it).

use std::thread::JoinHandle;
use std::time::Instant;

use farm::config::{PpoConfig, RunConfig};
use rand_chacha::ChaCha8Rng;
use tch::Device;

use crate::logs::metrics::UpdateMetrics;
use crate::net::agent::{Agent, AgentError};
use crate::ppo::optim::Adam;
use crate::ppo::rollout::Rollout;
use crate::ppo::update::{UpdateSettings, update};
use crate::stages::StageClock;

/// The learning copy and the rollouts on their way through it.
#[derive(Debug)]
pub(crate) struct Overlap {
    /// The learning copy (built like the agent; its frozen parts copied once), `None` while in flight.
    copy: Option<Learner>,
    queued: Option<Queued>,
    in_flight: Option<JoinHandle<Learned>>,
    /// The rollout of the last joined update, collected into next.
    spare: Option<Rollout>,
}

/// A network with Adam over its trainable variables.
#[derive(Debug)]
struct Learner {
    agent: Agent,
    opt: Adam,
    /// The frozen variables (never stepped) have been copied from the acting agent.
    frozen_copied: bool,
}

/// A full rollout waiting for its update: V(o_T) per env and the update that collected it.
#[derive(Debug)]
struct Queued {
    rollout: Rollout,
    bootstrap: Vec<f32>,
    collected_by: u64,
}

/// What an overlapped update hands back.
#[derive(Debug)]
struct Learned {
    copy: Learner,
    rng: ChaCha8Rng,
    rollout: Rollout,
    metrics: UpdateMetrics,
}

impl Overlap {
    /// The copy is built without its weight files: every variable is copied from the agent at
    /// the first update, after a checkpoint has been loaded into it.
    pub(crate) fn new(cfg: &RunConfig, hp: &PpoConfig, device: Device, adam_eps: f64) -> Result<Overlap, AgentError> {
        let agent = Agent::build(cfg, 1, device, false)?;
        let opt = Adam::new(&agent.vs, hp.lr, adam_eps);
        let copy = Learner { agent, opt, frozen_copied: false };
        Ok(Overlap { copy: Some(copy), queued: None, in_flight: None, spare: None })
    }

    /// At a full rollout: takes it for the next step to hand to the thread, leaving the spare
    /// rollout (or a new one) in its place.
    pub(crate) fn queue(&mut self, rollout: &mut Rollout, bootstrap: Vec<f32>, collected_by: u64) {
        let spare = self.spare.take().unwrap_or_else(|| Rollout::new(rollout.steps, rollout.envs, &rollout.h0));
        let rollout = std::mem::replace(rollout, spare);
        self.queued = Some(Queued { rollout, bootstrap, collected_by });
    }

    /// Hands the queued rollout, if any, to a thread that learns it on the copy, from `agent`'s
    /// weights, `opt`'s moments and `rng`'s minibatch order as they are now; `updates` is the
    /// trainer's count (the policy lag is measured from it).
    pub(crate) fn launch(&mut self, agent: &Agent, opt: &Adam, rng: &ChaCha8Rng, how: UpdateSettings, updates: u64) {
        let Some(q) = self.queued.take() else { return };
        let mut copy = self.copy.take().expect("the copy is back before a rollout is queued");
        if !copy.frozen_copied {
            copy.agent.vs.copy(&agent.vs).expect("the copy is built like the agent");
            if let Some(f) = copy.agent.net.frozen() {
                f.refresh(&copy.agent.vs);
            }
            copy.frozen_copied = true;
        }
        copy.opt.copy_from(opt);
        let mut rng = rng.clone();
        let policy_lag = updates - q.collected_by;
        self.in_flight = Some(std::thread::spawn(move || {
            let started = Instant::now();
            // its stages are not timed: they run beside acting's
            let stages = StageClock::default();
            let mut metrics = update(&copy.agent.net, &mut copy.opt, &mut rng, &q.rollout, &q.bootstrap, &how, &stages);
            metrics.update_seconds = started.elapsed().as_secs_f64();
            metrics.policy_lag = policy_lag;
            Learned { copy, rng, rollout: q.rollout, metrics }
        }));
    }

    /// Waits for the update in flight, if any: its weights and moments go into `opt` (whose
    /// variables are the acting agent's), its minibatch order into `rng`. Its metrics, and the
    /// seconds waited.
    pub(crate) fn join(&mut self, opt: &mut Adam, rng: &mut ChaCha8Rng) -> Option<(UpdateMetrics, f64)> {
        let handle = self.in_flight.take()?;
        let waited = Instant::now();
        let l = handle.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        let waited = waited.elapsed().as_secs_f64();
        opt.copy_from(&l.copy.opt);
        *rng = l.rng;
        self.copy = Some(l.copy);
        self.spare = Some(l.rollout);
        Some((l.metrics, waited))
    }
}
