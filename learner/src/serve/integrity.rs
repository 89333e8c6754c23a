//! Message integrity, as a pure function: given what the server expects of one worker slot and an
//! observation message as it arrived (header and payload), the [`Verdict`]. No shared memory and
//! no clock are involved, so every case is tested here without iceoryx2.
//!
//! A message must carry our magic, version, the slot's worker id and a layout that fits the run's
//! shape; within a generation, the worker's message counter (`step`) and every env's `env_step`
//! must go up by exactly one. A worker restarted by the orchestrator announces `generation + 1`,
//! which starts the slot afresh; messages of older generations still in flight are stale.

use shm_schema::{OBS_MAGIC, ObsHeader, ObsShape, ObsView, SCHEMA_VERSION};

/// What the server expects of one worker slot: the counters of its current generation.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Expected {
    /// The generation of the slot's messages; `None` before its first message.
    pub generation: Option<u32>,
    /// The `step` of the last message accepted from this generation.
    pub last_step: Option<u64>,
    /// The `env_step` each env must send next.
    pub next_env_step: Vec<Option<u64>>,
}

/// What to do with an arriving message.
#[derive(Clone, Debug, PartialEq)]
pub enum Verdict {
    /// Keep it; [`Accepted`] says what was skipped or repeated on the way (nothing: all is well).
    Accept(Accepted),
    /// The message repeats one already accepted, or comes before it: dropped.
    Duplicate(String),
    /// Bad magic, version, worker id, layout or size: dropped.
    Corrupt(String),
    /// From a generation older than the slot's (in flight from a replaced process): dropped.
    Stale { generation: u32, current: u32 },
}

/// An accepted message, and what it says about the messages before it.
#[derive(Clone, Debug, PartialEq)]
pub struct Accepted {
    /// The slot's counters after this message.
    pub next: Expected,
    /// The message is the first of its generation: the slot starts afresh (its unanswered
    /// message, if any, is dropped) and the worker's envs start fresh episodes.
    pub new_generation: bool,
    /// The generation the new one replaces (a restart), when the slot had one.
    pub replaces: Option<u32>,
    /// Messages or env steps skipped.
    pub lost: u64,
    /// Env steps seen again, or a message that came before the previous one was answered.
    pub duplicates: u64,
    /// One line per problem, for the log (and, in check mode, the failure).
    pub issues: Vec<String>,
}

impl Accepted {
    /// Nothing lost or repeated.
    pub fn is_clean(&self) -> bool {
        self.lost == 0 && self.duplicates == 0
    }
}

/// Judges the message `header` + `payload` that arrived in worker slot `worker`, against the
/// slot's `expected` counters and the run's `shape`. `unanswered`: the slot holds a message that
/// has not been answered yet (the worker should wait for its answer before sending again).
pub fn check(
    worker: usize,
    expected: &Expected,
    unanswered: bool,
    shape: &ObsShape,
    header: &ObsHeader,
    payload: &[u8],
) -> Verdict {
    let (h, k) = (header, worker);
    let view = match well_formed(worker, shape, header, payload) {
        Ok(v) => v,
        Err(why) => return Verdict::Corrupt(why),
    };
    let mut next = expected.clone();
    let mut accepted = Accepted {
        next: Expected::default(),
        new_generation: false,
        replaces: None,
        lost: 0,
        duplicates: 0,
        issues: vec![],
    };
    match expected.generation {
        Some(g) if h.generation < g => return Verdict::Stale { generation: h.generation, current: g },
        Some(g) if h.generation == g => {}
        known => {
            accepted.new_generation = true;
            accepted.replaces = known;
            next =
                Expected { generation: Some(h.generation), last_step: None, next_env_step: vec![None; shape.num_envs] };
        }
    }
    // The message counter of this generation.
    if let Some(last) = next.last_step {
        if h.step <= last {
            return Verdict::Duplicate(format!(
                "worker {k} generation {}: message {} again (last {last})",
                h.generation, h.step
            ));
        }
        if h.step > last + 1 {
            accepted.lost += h.step - last - 1;
            accepted.issues.push(format!(
                "worker {k} generation {}: messages {}..{} lost",
                h.generation,
                last + 1,
                h.step
            ));
        }
    }
    if unanswered && !accepted.new_generation {
        // A second observation before the first was answered: the worker broke lock-step.
        accepted.duplicates += 1;
        accepted
            .issues
            .push(format!("worker {k}: observation {} arrived before the previous one was answered", h.step));
    }
    env_counters(k, &view, &mut next, &mut accepted);
    next.last_step = Some(h.step);
    accepted.next = next;
    Verdict::Accept(accepted)
}

/// The message's view, or why it is corrupt: a bad magic or version, another worker's id, a
/// layout that does not parse or is not the run's.
fn well_formed<'a>(worker: usize, shape: &ObsShape, h: &ObsHeader, payload: &'a [u8]) -> Result<ObsView<'a>, String> {
    if h.magic != OBS_MAGIC || h.version != SCHEMA_VERSION {
        return Err(format!("magic {:#x} version {}", h.magic, h.version));
    }
    if h.worker_id as usize != worker {
        return Err(format!("header says worker {}", h.worker_id));
    }
    let v = ObsShape::of_header(h).and_then(|s| ObsView::new(s, payload)).map_err(|e| e.to_string())?;
    if v.shape() != shape {
        return Err(format!(
            "{} envs of {}x{}, the run config says {} of {}x{}",
            v.shape().num_envs,
            v.shape().width,
            v.shape().height,
            shape.num_envs,
            shape.width,
            shape.height
        ));
    }
    Ok(v)
}

/// The counter of each env: a step again counts as a duplicate, a gap as lost steps.
fn env_counters(k: usize, view: &ObsView, next: &mut Expected, accepted: &mut Accepted) {
    next.next_env_step.resize(view.records().len(), None);
    for (e, r) in view.records().iter().enumerate() {
        if let Some(want) = next.next_env_step[e]
            && r.env_step != want
        {
            if r.env_step < want {
                accepted.duplicates += 1;
            } else {
                accepted.lost += r.env_step - want;
            }
            accepted.issues.push(format!("worker {k} env {e}: env_step {} where {want} was due", r.env_step));
        }
        next.next_env_step[e] = Some(r.env_step + 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farm::stepper::PayloadBuf;
    use shm_schema::{GESTURE_DIMS, GESTURE_FRAMES, ObsSections};

    const W: u32 = 8;
    const H: u32 = 6;

    fn shape(envs: usize) -> ObsShape {
        ObsShape::new(envs, W, H)
    }

    /// A well-formed message of worker `worker` whose envs report `env_steps`.
    fn message(worker: u32, generation: u32, step: u64, env_steps: &[u64]) -> (ObsHeader, PayloadBuf) {
        let s = shape(env_steps.len());
        let header = ObsHeader {
            magic: OBS_MAGIC,
            version: SCHEMA_VERSION,
            worker_id: worker,
            generation,
            step,
            num_envs: env_steps.len() as u32,
            width: W,
            height: H,
            gesture_frames: GESTURE_FRAMES as u32,
            gesture_dims: GESTURE_DIMS as u32,
            finished: 0,
            layout: s.layout,
            timing: Default::default(),
        };
        let mut buf = PayloadBuf::new(&s.layout);
        let sections = ObsSections::new(&s, buf.bytes_mut()).unwrap();
        for (r, &n) in sections.records.iter_mut().zip(env_steps) {
            r.env_step = n;
        }
        (header, buf)
    }

    fn judge(expected: &Expected, unanswered: bool, (h, p): &(ObsHeader, PayloadBuf)) -> Verdict {
        check(h.worker_id as usize, expected, unanswered, &shape(2), h, p.bytes())
    }

    fn accepted(v: Verdict) -> Accepted {
        match v {
            Verdict::Accept(a) => a,
            other => panic!("not accepted: {other:?}"),
        }
    }

    /// Worker 1's slot after generation 0 sent messages 0..=3, its envs at env_step 3 and 7.
    fn after_step_3() -> Expected {
        Expected { generation: Some(0), last_step: Some(3), next_env_step: vec![Some(4), Some(8)] }
    }

    #[test]
    fn the_first_message_opens_a_generation() {
        let a = accepted(judge(&Expected::default(), false, &message(1, 0, 0, &[0, 5])));
        assert!(a.is_clean() && a.issues.is_empty());
        assert!(a.new_generation);
        assert_eq!(a.replaces, None);
        assert_eq!(a.next, Expected { generation: Some(0), last_step: Some(0), next_env_step: vec![Some(1), Some(6)] });
    }

    #[test]
    fn the_next_message_in_line_is_ok() {
        let a = accepted(judge(&after_step_3(), false, &message(1, 0, 4, &[4, 8])));
        assert!(a.is_clean() && a.issues.is_empty() && !a.new_generation);
        assert_eq!(a.next, Expected { generation: Some(0), last_step: Some(4), next_env_step: vec![Some(5), Some(9)] });
    }

    #[test]
    fn skipped_messages_and_env_steps_are_lost() {
        // messages 4 and 5 never came; env 0 skipped 2 steps with them, env 1 skipped 3
        let a = accepted(judge(&after_step_3(), false, &message(1, 0, 6, &[6, 11])));
        assert_eq!((a.lost, a.duplicates), (2 + 2 + 3, 0));
        assert_eq!(a.issues.len(), 3, "{:?}", a.issues);
        assert!(a.issues[0].contains("messages 4..6 lost"), "{:?}", a.issues);
        assert!(a.issues[1].contains("env 0: env_step 6 where 4 was due"), "{:?}", a.issues);
        assert_eq!(a.next.next_env_step, vec![Some(7), Some(12)]);
    }

    #[test]
    fn a_repeated_message_is_a_duplicate_and_dropped() {
        for step in [3, 2] {
            match judge(&after_step_3(), false, &message(1, 0, step, &[4, 8])) {
                Verdict::Duplicate(why) => assert!(why.contains(&format!("message {step} again (last 3)")), "{why}"),
                other => panic!("{other:?}"),
            }
        }
        // an env counter going backwards in a new message counts as a duplicate step
        let a = accepted(judge(&after_step_3(), false, &message(1, 0, 4, &[4, 7])));
        assert_eq!((a.lost, a.duplicates), (0, 1));
        assert!(a.issues[0].contains("env 1: env_step 7 where 8 was due"), "{:?}", a.issues);
    }

    #[test]
    fn a_message_before_the_answer_breaks_lock_step() {
        let a = accepted(judge(&after_step_3(), true, &message(1, 0, 4, &[4, 8])));
        assert_eq!((a.lost, a.duplicates), (0, 1));
        assert!(a.issues[0].contains("arrived before the previous one was answered"), "{:?}", a.issues);
    }

    #[test]
    fn malformed_messages_are_corrupt_with_a_reason() {
        let corrupt = |v: Verdict| match v {
            Verdict::Corrupt(why) => why,
            other => panic!("not corrupt: {other:?}"),
        };
        let mut m = message(1, 0, 4, &[4, 8]);
        m.0.magic = 0xDEAD;
        assert!(corrupt(judge(&after_step_3(), false, &m)).contains("magic 0xdead"));
        let mut m = message(1, 0, 4, &[4, 8]);
        m.0.version = SCHEMA_VERSION + 1;
        assert!(corrupt(judge(&after_step_3(), false, &m)).contains("version"));
        // sent to slot 0 but says worker 1
        let m = message(1, 0, 4, &[4, 8]);
        let why = corrupt(check(0, &after_step_3(), false, &shape(2), &m.0, m.1.bytes()));
        assert!(why.contains("header says worker 1"), "{why}");
        // a layout that does not match the envs and frame size it announces
        let mut m = message(1, 0, 4, &[4, 8]);
        m.0.layout.gesture_offset += 64;
        assert!(corrupt(judge(&after_step_3(), false, &m)).contains("layout"));
        // a payload shorter than the layout
        let m = message(1, 0, 4, &[4, 8]);
        let short = &m.1.bytes()[..m.1.bytes().len() - 64];
        let why = corrupt(check(1, &after_step_3(), false, &shape(2), &m.0, short));
        assert!(why.contains("payload is"), "{why}");
        // well formed, but not the run's shape
        let why = corrupt(judge(&after_step_3(), false, &message(1, 0, 4, &[4, 8, 9])));
        assert!(why.contains("3 envs of 8x6, the run config says 2 of 8x6"), "{why}");
    }

    #[test]
    fn an_older_generation_is_stale() {
        let slot = Expected { generation: Some(2), ..after_step_3() };
        assert_eq!(judge(&slot, false, &message(1, 1, 4, &[4, 8])), Verdict::Stale { generation: 1, current: 2 });
    }

    #[test]
    fn a_newer_generation_starts_the_slot_afresh() {
        // the restarted process counts from 0 again, and its first message is not "early"
        let a = accepted(judge(&after_step_3(), true, &message(1, 1, 0, &[0, 0])));
        assert!(a.is_clean() && a.issues.is_empty());
        assert!(a.new_generation);
        assert_eq!(a.replaces, Some(0));
        assert_eq!(a.next, Expected { generation: Some(1), last_step: Some(0), next_env_step: vec![Some(1), Some(1)] });
    }
}
