//! One env's policy over a pipe (`learner act`, started by `orchestrator live` for each checkpoint
//! a session shows): an observation payload in — the bytes a worker writes for one env, after
//! their length as a little-endian u64, on stdin — and the action out, with the policy's
//! probability of each action and its value: one JSON line on stdout. The recurrent memory
//! resets where the record says an episode starts, as in the farm; actions are sampled from the
//! checkpoint's own random stream (or the most likely one with `greedy`), as `eval` does.

use std::io::{BufRead, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};
use tch::Device;

use farm::config::RunConfig;
use farm::stepper::PayloadBuf;
use shm_schema::{ObsShape, ObsView};

use crate::net::agent::ActMode;
use crate::obs::{EnvBatch, FrameView, GestureView};
use crate::ppo::checkpoint;
use crate::serve::batch::as_f16;
use crate::serve::ppo_policy::env_step;

/// What the policy answers to one observation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Answer {
    /// Index of [`shm_schema::action`]: MoveAhead, RotateLeft, RotateRight, Stop.
    pub action: u8,
    /// The policy's probability of each action.
    pub probs: Vec<f32>,
    /// The critic's value of the observation.
    pub value: f32,
}

/// Answers observations read from `input` until it closes; returns how many.
pub fn serve_pipe(
    cfg: &RunConfig,
    checkpoint_path: &Path,
    device: Device,
    greedy: bool,
    mut input: impl BufRead,
    mut output: impl Write,
) -> anyhow::Result<u64> {
    tch::manual_seed(cfg.run.seed as i64);
    let mut agent = checkpoint::load_agent(cfg, 1, device, checkpoint_path)?;
    let shape = ObsShape::new(1, cfg.env.width, cfg.env.height);
    let need = shape.layout.total_len as usize;
    let mut buf = PayloadBuf::new(&shape.layout);
    let mode = if greedy { ActMode::Greedy } else { ActMode::Sample };
    // one line first: the caller knows the checkpoint loaded (a bad one fails before it)
    writeln!(output, "{}", serde_json::json!({"ready": true, "width": cfg.env.width, "height": cfg.env.height}))?;
    output.flush()?;
    let mut answered = 0;
    loop {
        let mut len = [0u8; 8];
        match input.read_exact(&mut len) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(answered),
            Err(e) => return Err(e.into()),
        }
        let len = u64::from_le_bytes(len) as usize;
        anyhow::ensure!(
            len == need,
            "an observation of {len} bytes; {}x{} frames need {need}",
            shape.width,
            shape.height
        );
        input.read_exact(&mut buf.bytes_mut()[..len])?;
        let view = ObsView::new(shape, &buf.bytes()[..len])?;
        let steps = [env_step(&view.records()[0])];
        let frames = vec![FrameView {
            envs: 1,
            rgb: view.rgb_all(),
            depth: view.depth_all(),
            gesture: GestureView::F16(as_f16(view.gesture_bits_all())),
            device: None,
        }];
        let obs = EnvBatch { height: shape.height, width: shape.width, frames, envs: &steps };
        let (actions, probs) = agent.act_explained(&obs, mode)?;
        let a = Answer { action: actions.actions[0] as u8, probs, value: actions.values[0] };
        serde_json::to_writer(&mut output, &a)?;
        writeln!(output)?;
        output.flush()?;
        answered += 1;
    }
}
