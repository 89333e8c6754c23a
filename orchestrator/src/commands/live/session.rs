//! One browser tab's session: its own simulator (two, side by side, when two checkpoints are
//! compared on one program), the checkpoints it has asked for (one `learner act` a side each),
//! its webcam's landmark model and its record. It runs on a thread of its own and
//! hears the page through a channel; when the tab closes the channel does, and everything the
//! session started is dropped with it.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use anyhow::Context;
use tokio::sync::mpsc::UnboundedSender;

use farm::metrics::{EpisodeResult, scores};
use worker::dataset::{Dataset, write_subset};
use worker::gesture::{INTERVENTION_NAMES, Motion, intervention};
use worker::humanoid::Humanoid;

use super::gesture::{PersonGesture, arm_name, muscles, read_upload};
use super::picture::png_base64;
use super::policy::{Checkpoint, Policy};
use super::record::{EpisodeRecord, Recorder, Sim, episode_config};
use super::webcam::{Webcam, refusal};
use super::wire::{
    EpisodeEnd, GestureSource, Interventions, MAX_SPEED, Outcome, Placement, Side, StepRecord, StepView, ToPage,
    ToServer,
};
use super::{avatar, room};
use crate::commands::program::{dataset_program, parse_ref};
use crate::report::map::TopDownMap;

/// Steps a person's call (a wave, the key) shows the intervention gesture for.
pub const CALL_STEPS: u32 = 3;
/// DTS counts the distance beyond this (m), as `eval`'s default.
const DTS_THRESHOLD: f64 = 1.5;

/// What the server holds for every session.
pub struct Shared {
    pub dataset: Arc<Dataset>,
    pub checkpoints: Vec<Checkpoint>,
    /// Where sessions are recorded.
    pub out: PathBuf,
    /// Each split's rooms, where the person may place a program.
    pub rooms: Vec<(String, Vec<String>)>,
}

impl Shared {
    pub fn new(dataset: Arc<Dataset>, checkpoints: Vec<Checkpoint>, out: PathBuf) -> Shared {
        let rooms = room::rooms(&dataset);
        Shared { dataset, checkpoints, out, rooms }
    }
}

/// What reaches a session from its tab.
pub enum Input {
    Message(ToServer),
    /// A webcam frame (a JPEG, unless the page is wrong) and when it arrived.
    Frame(Vec<u8>, Instant),
    /// A file uploaded from the page (`super::server`'s `/upload`): a video, or a motion file.
    Upload {
        name: String,
        bytes: Vec<u8>,
    },
}

/// What an episode runs on: a dataset program (SPLIT:INDEX), or one the person placed.
pub enum Program {
    Dataset(String),
    Placed(Placement),
}

/// One robot of an episode: a checkpoint acting in a simulator of its own, recorded as an
/// episode of its own.
struct Robot {
    number: usize,
    checkpoint: usize,
    sim: Sim,
    rec: Recorder,
    ended: bool,
}

/// An episode under way: one program, one gesture, one source of interventions, and one robot
/// a side, stepped in lockstep.
struct Episode {
    program: String,
    gesture: GestureSource,
    interventions: Interventions,
    robots: Vec<Robot>,
}

impl Episode {
    fn ended(&self) -> bool {
        self.robots.iter().all(|r| r.ended)
    }
}

/// A session's state; [`run`] drives it.
pub struct Session {
    shared: Arc<Shared>,
    pub dir: PathBuf,
    tx: UnboundedSender<ToPage>,
    /// A side's policy for each checkpoint (`[side][checkpoint]`): each keeps its own recurrent
    /// memory, so one checkpoint on both sides runs twice.
    policies: [Vec<Option<Policy>>; 2],
    episode: Option<Episode>,
    episodes: usize,
    running: Option<Duration>,
    webcam: Option<Webcam>,
    /// The last gesture captured from the webcam, and the last uploaded.
    captured: Option<PersonGesture>,
    uploaded: Option<PersonGesture>,
    calls_left: u32,
}

/// Runs a session until its tab closes.
pub fn run(shared: Arc<Shared>, id: String, rx: Receiver<Input>, tx: UnboundedSender<ToPage>) {
    let mut s = Session::new(shared, &id, tx);
    let mut next = Instant::now();
    loop {
        let input = match s.running.filter(|_| s.episode.as_ref().is_some_and(|e| !e.ended())) {
            Some(period) => match rx.recv_timeout(next.saturating_duration_since(Instant::now())) {
                Ok(i) => Some(i),
                Err(RecvTimeoutError::Timeout) => {
                    next = Instant::now().max(next) + period;
                    None
                }
                Err(RecvTimeoutError::Disconnected) => return,
            },
            None => match rx.recv() {
                Ok(i) => Some(i),
                Err(_) => return,
            },
        };
        let done = match input {
            None => s.step(),
            Some(Input::Message(ToServer::Run { speed })) => {
                let speed = if speed.is_finite() { speed.clamp(0.5, MAX_SPEED) } else { 10.0 };
                s.running = Some(Duration::from_secs_f32(1.0 / speed));
                next = Instant::now();
                Ok(())
            }
            Some(Input::Message(m)) => s.handle(m),
            Some(Input::Frame(jpeg, at)) => {
                if let Err(e) = s.frame(&jpeg, at) {
                    s.send(ToPage::FrameRefused { message: format!("{e:#}") });
                }
                Ok(())
            }
            Some(Input::Upload { name, bytes }) => s.upload(&name, &bytes),
        };
        if let Err(e) = done {
            s.send(ToPage::Error { message: format!("{e:#}") });
        }
    }
}

impl Session {
    /// A session recorded in the server's output folder under `id`, speaking through `tx`.
    pub fn new(shared: Arc<Shared>, id: &str, tx: UnboundedSender<ToPage>) -> Session {
        let n = shared.checkpoints.len();
        Session {
            dir: shared.out.join(id),
            shared,
            tx,
            policies: [0, 1].map(|_| (0..n).map(|_| None).collect()),
            episode: None,
            episodes: 0,
            running: None,
            webcam: None,
            captured: None,
            uploaded: None,
            calls_left: 0,
        }
    }

    fn send(&self, m: ToPage) {
        // a closed tab: the receiving end is gone and the session ends at its next input
        let _ = self.tx.send(m);
    }

    fn handle(&mut self, m: ToServer) -> anyhow::Result<()> {
        match m {
            ToServer::Start { program, placed, checkpoint, versus, gesture, interventions } => {
                self.running = None;
                let program = match (program, placed) {
                    (Some(p), None) => Program::Dataset(p),
                    (None, Some(p)) => Program::Placed(p),
                    _ => anyhow::bail!("start: a dataset program (`program`) or one placed (`placed`), one of the two"),
                };
                self.start(&program, checkpoint, versus, gesture, interventions)
            }
            ToServer::Room { split, room } => {
                let view = room::view(&self.shared.dataset, &split, &room)?;
                self.send(ToPage::Room(view));
                Ok(())
            }
            ToServer::Run { .. } => Ok(()),
            ToServer::Pause => {
                self.running = None;
                Ok(())
            }
            ToServer::Step => {
                self.running = None;
                self.step()
            }
            ToServer::Intervene => {
                self.calls_left = CALL_STEPS;
                Ok(())
            }
            ToServer::CaptureGesture { seconds } => {
                anyhow::ensure!(self.webcam.is_some(), "no webcam frames yet: turn the camera on first");
                anyhow::ensure!((1.0..=10.0).contains(&seconds), "a capture of {seconds} s: 1 to 10 seconds");
                self.webcam.as_mut().expect("checked").start_capture(seconds);
                Ok(())
            }
        }
    }

    /// Starts `program` with checkpoint `k`, and `versus` beside it.
    pub fn start(
        &mut self,
        program: &Program,
        k: usize,
        versus: Option<usize>,
        gesture: GestureSource,
        interventions: Interventions,
    ) -> anyhow::Result<()> {
        let checkpoints = std::iter::once(k).chain(versus).collect::<Vec<_>>();
        for (side, &c) in checkpoints.iter().enumerate() {
            let field = ["checkpoint", "versus"][side];
            anyhow::ensure!(c < self.shared.checkpoints.len(), "{field} {c}: there is no such checkpoint");
        }
        let ds = &self.shared.dataset;
        let (name, split, p, own) = match program {
            Program::Dataset(r) => {
                let (split, i) =
                    parse_ref(r).with_context(|| format!("program `{r}` is not SPLIT:INDEX (e.g. val:17)"))?;
                let (p, own) = dataset_program(ds, split, i).with_context(|| format!("program {r}"))?;
                (r.clone(), split, p, own)
            }
            Program::Placed(placed) => {
                let (split, p, own) = room::program(ds, placed)?;
                ("placed".to_string(), split, p, own)
            }
        };
        let human = Humanoid::seeded(p.seed);
        let person = |g: &Option<PersonGesture>, what: &str| -> anyhow::Result<Motion> {
            let g = g.as_ref().with_context(|| format!("no gesture {what} yet"))?;
            g.motion(human.skeleton()).with_context(|| format!("the gesture {what}"))
        };
        let motion = match gesture {
            GestureSource::Program => own,
            GestureSource::Webcam => person(&self.captured, "captured from the webcam")?,
            GestureSource::Upload => person(&self.uploaded, "uploaded")?,
        };
        let mut robots = Vec::new();
        let mut sides = Vec::new();
        for (side, &c) in checkpoints.iter().enumerate() {
            let ck = &self.shared.checkpoints[c];
            let number = self.episodes + 1 + side;
            let dir = self.dir.join(format!("episode-{number:03}"));
            let data = dir.join("dataset");
            write_subset(&data, ds, split, &[(p.clone(), motion.as_flat().to_vec())])
                .with_context(|| format!("writing {}", data.display()))?;
            let cfg = episode_config(&ck.cfg, &data, split);
            let rec = Recorder::new(&dir, &cfg)?;
            if self.policies[side][c].is_none() {
                self.policies[side][c] = Some(Policy::start(ck, &ck.config)?);
            }
            let sim = Sim::start(&cfg, interventions == Interventions::Person)?;
            // each run's seed draws the intervention gesture its person shows
            let iv = sim.pool.env(0).context("the episode's env")?.intervention_index() as usize;
            let film = match sides.iter().find(|s: &&Side| s.intervention.name == INTERVENTION_NAMES[iv]) {
                Some(beside) => beside.intervention.clone(),
                None => avatar::film(&human, &intervention(iv), INTERVENTION_NAMES[iv])?,
            };
            sides.push(Side { number, checkpoint: ck.name.clone(), intervention: film });
            robots.push(Robot { number, checkpoint: c, sim, rec, ended: false });
        }
        self.episodes += robots.len();
        self.calls_left = 0;

        let scene = ds.scene(p.scene_id())?;
        let mut map = TopDownMap::new(&scene, 60.0);
        let others: Vec<usize> = scene.instances(p.target).filter(|&o| o != p.target_object).collect();
        map.person([p.human_pos[0], p.human_pos[2]], p.human_yaw).target(p.target_object).other_instances(&others);
        self.send(ToPage::Episode {
            program: name.clone(),
            label: format!("{} {name} → {}", p.scene, p.target.name()),
            sides,
            map_png: png_base64(&map.to_rgb_image())?,
            map_transform: map.transform(),
            target: [p.target_pos[0], p.target_pos[2]],
            person: [p.human_pos[0], p.human_pos[2]],
            gesture,
            interventions,
            referencing: avatar::film(&human, &motion, "referencing")?,
        });
        self.episode = Some(Episode { program: name, gesture, interventions, robots });
        Ok(())
    }

    /// Each robot still under way takes a step: its policy acts on its observation, its
    /// simulator takes the action; the page sees both, and each side's end when it comes. A
    /// person's call reaches both sides at the same step.
    pub fn step(&mut self) -> anyhow::Result<()> {
        let Some(e) = self.episode.as_mut().filter(|e| !e.ended()) else {
            anyhow::bail!("no episode under way: start one");
        };
        let beside = |side: usize| e.robots.get(1 - side).map(|r| r.number);
        let besides: Vec<Option<usize>> = (0..e.robots.len()).map(beside).collect();
        let call = self.calls_left > 0;
        for (side, robot) in e.robots.iter_mut().enumerate().filter(|(_, r)| !r.ended) {
            let policy = self.policies[side][robot.checkpoint].as_mut().expect("started with the episode");
            let Some(outcome) = step_robot(robot, policy, side, e.interventions, call, &self.tx)? else {
                continue;
            };
            robot.rec.finish(&EpisodeRecord {
                program: e.program.clone(),
                checkpoint: self.shared.checkpoints[robot.checkpoint].file.clone(),
                gesture: e.gesture,
                interventions: e.interventions,
                beside: besides[side],
                outcome: outcome.clone(),
            })?;
            let record = robot.rec.dir.display().to_string();
            let _ = self.tx.send(ToPage::End(EpisodeEnd { side, number: robot.number, outcome, record }));
        }
        self.calls_left = self.calls_left.saturating_sub(1);
        Ok(())
    }

    /// A webcam frame: checked, read by the landmark model, answered; a wave calls for an
    /// intervention, a capture under way takes it.
    pub fn frame(&mut self, jpeg: &[u8], at: Instant) -> anyhow::Result<()> {
        if let Some(why) = refusal(jpeg) {
            anyhow::bail!(why);
        }
        if self.webcam.is_none() {
            self.webcam = Some(Webcam::start()?);
        }
        let cam = self.webcam.as_mut().expect("started");
        let f = cam.read(jpeg, at)?;
        let waving = cam.waving();
        if waving {
            self.calls_left = CALL_STEPS;
        }
        let capturing = cam.capturing();
        let _ = self.tx.send(ToPage::FrameSeen { person: f.pose.is_some(), waving, capturing });
        if let Some(frames) = cam.captured() {
            // fitted to a default person here to say what was found; to each program's at its start
            let c = muscles(Humanoid::seeded(0).skeleton(), &frames).context("the webcam")?;
            let _ = self.tx.send(ToPage::Captured {
                arm: arm_name(c.side).into(),
                seconds: [c.times[c.span.0], c.times[c.span.1]],
                frames: c.frames.len(),
                person_frames: c.person_frames,
            });
            self.captured = Some(PersonGesture::Landmarks(frames));
        }
        Ok(())
    }

    /// An uploaded file: kept in the session's folder, read into the person's gesture.
    pub fn upload(&mut self, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
        let (gesture, told) = read_upload(&self.dir.join("uploads"), name, bytes)?;
        self.uploaded = Some(gesture);
        self.send(told);
        Ok(())
    }
}

/// One step of one robot: recorded, shown on the page as `side`; its outcome when the episode
/// ended with it.
fn step_robot(
    robot: &mut Robot,
    policy: &mut Policy,
    side: usize,
    interventions: Interventions,
    call: bool,
    tx: &UnboundedSender<ToPage>,
) -> anyhow::Result<Option<Outcome>> {
    let view = robot.sim.view();
    let r = view.records()[0];
    let rule = robot.sim.pool.env(0).context("the episode's env")?.rule_kind();
    let a = policy.act(robot.sim.payload())?;
    let (w, h) = (robot.sim.shape.width as u32, robot.sim.shape.height as u32);
    let rgb = image::RgbImage::from_raw(w, h, view.rgb(0).to_vec()).context("frame size")?;
    // depth: near is bright, 10 m and beyond black
    let depth = image::GrayImage::from_raw(w, h, view.depth(0).iter().map(|d| 255 - (d >> 8) as u8).collect())
        .context("frame size")?;
    let record = StepRecord {
        step: r.episode_step,
        robot: r.robot,
        shown: r.gesture_kind,
        rule,
        action: a.action,
        probs: a.probs,
        value: a.value,
    };
    robot.rec.step(&record)?;
    let (rgb_png, depth_png) = (png_base64(&rgb)?, png_base64(&depth)?);
    let _ = tx.send(ToPage::Step(StepView { side, record, rgb_png, depth_png, distance: r.distance }));
    if interventions == Interventions::Person {
        robot.sim.pool.set_person_calls(0, Some(call));
    }
    robot.sim.step(a.action)?;
    let r = robot.sim.view().records()[0];
    if r.terminated == 0 && r.truncated == 0 {
        return Ok(None);
    }
    robot.ended = true;
    let result = EpisodeResult::from_record(&r, 0, 0, 0);
    let first = scores([&result], Some(1), DTS_THRESHOLD);
    Ok(Some(Outcome {
        steps: result.steps,
        success: first.sr > 0.0,
        spl: first.spl / 100.0,
        dts: first.dts,
        success_any_stop: result.success,
    }))
}
