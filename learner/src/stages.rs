//! Acting and updating timed stage by stage (`learner serve --profile-stages`): a
//! [`StageClock`] charges the wall time since its last mark to a stage, after waiting for the
//! device to finish what the stage queued. Off (the default), a lap is one branch and never
//! synchronizes.

use std::cell::Cell;
use std::time::Instant;

use farm::profile::StageTimes;
use tch::Device;

/// The stages of [`StageTimes`], in the order they run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    ActInputs,
    ActVisual,
    ActRest,
    ActSample,
    ActStore,
    UpdatePrepare,
    UpdateBackward,
    UpdateStep,
}

/// Cumulative stage times, or nothing when off. Interior mutability: the network's `&self`
/// methods (preparing the inputs, encoding) mark stages too.
#[derive(Debug, Default)]
pub struct StageClock {
    on: Option<Running>,
}

#[derive(Debug)]
struct Running {
    device: Device,
    mark: Cell<Instant>,
    times: Cell<StageTimes>,
}

impl StageClock {
    /// A clock that times stages on `device`.
    pub fn on(device: Device) -> StageClock {
        StageClock {
            on: Some(Running { device, mark: Cell::new(Instant::now()), times: Cell::new(StageTimes::default()) }),
        }
    }

    /// The times so far; `None` when off.
    pub fn times(&self) -> Option<StageTimes> {
        self.on.as_ref().map(|r| r.times.get())
    }

    /// Starts an acting call (`round`) or an update: the next lap counts from now.
    pub fn start(&self, round: bool) {
        if let Some(r) = &self.on {
            r.mark.set(Instant::now());
            let mut t = r.times.get();
            if round {
                t.rounds += 1;
            } else {
                t.updates += 1;
            }
            r.times.set(t);
        }
    }

    /// Charges the time since the last mark to `stage`, once the device is done with its work.
    pub fn lap(&self, stage: Stage) {
        let Some(r) = &self.on else { return };
        if let Device::Cuda(i) = r.device {
            tch::Cuda::synchronize(i as i64);
        }
        let now = Instant::now();
        let s = now.duration_since(r.mark.replace(now)).as_secs_f64();
        let mut t = r.times.get();
        *match stage {
            Stage::ActInputs => &mut t.act_inputs_s,
            Stage::ActVisual => &mut t.act_visual_s,
            Stage::ActRest => &mut t.act_rest_s,
            Stage::ActSample => &mut t.act_sample_s,
            Stage::ActStore => &mut t.act_store_s,
            Stage::UpdatePrepare => &mut t.update_prepare_s,
            Stage::UpdateBackward => &mut t.update_backward_s,
            Stage::UpdateStep => &mut t.update_step_s,
        } += s;
        r.times.set(t);
    }
}
