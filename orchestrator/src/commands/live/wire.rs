//! What the page and the server say to each other over the WebSocket: one enum a direction, as
//! JSON text messages tagged by `type`. The webcam's frames are the one exception: each is a
//! binary message holding a JPEG, answered by [`ToPage::FrameSeen`] before the page sends the next.

use serde::{Deserialize, Serialize};

/// Where the person's referencing gesture comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GestureSource {
    /// The program's own recording.
    #[default]
    Program,
    /// The gesture last captured from the webcam ([`ToServer::CaptureGesture`]).
    Webcam,
}

/// Who decides when the intervention gesture is shown.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Interventions {
    /// The angle rule (§4.4.1), as in training.
    #[default]
    Rule,
    /// The person: a wave in front of the camera, or the page's key.
    Person,
}

/// The page to the server.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ToServer {
    /// A new episode: `program` is SPLIT:INDEX, `checkpoint` an index into the server's list.
    Start {
        program: String,
        checkpoint: usize,
        #[serde(default)]
        gesture: GestureSource,
        #[serde(default)]
        interventions: Interventions,
    },
    /// Step on its own, `speed` steps a second (at most [`MAX_SPEED`]).
    Run {
        speed: f32,
    },
    Pause,
    /// One step, paused.
    Step,
    /// The person calls for the intervention gesture now (the page's key; a wave does the same).
    Intervene,
    /// Capture the person's gesture from the next `seconds` of webcam frames.
    CaptureGesture {
        seconds: f32,
    },
}

/// Steps a second a session runs at most.
pub const MAX_SPEED: f32 = 60.0;

/// A world point's place on the map picture: column = a·x + b·z + c, row = d·x + e·z + f.
pub type MapTransform = [f32; 6];

/// The server to the page.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ToPage {
    /// On connecting: what can be chosen.
    Hello { checkpoints: Vec<CheckpointInfo>, splits: Vec<(String, usize)>, session: String },
    /// An episode began.
    Episode {
        number: usize,
        program: String,
        label: String,
        checkpoint: String,
        /// The room from above (PNG, base64) and where world points land on it.
        map_png: String,
        map_transform: MapTransform,
        target: [f32; 2],
        person: [f32; 2],
        gesture: GestureSource,
        interventions: Interventions,
    },
    /// One step: the observation the policy acted on and what it answered.
    Step(StepView),
    /// The episode ended.
    End(EpisodeEnd),
    /// A webcam frame was read: whether a person was found, and whether they are waving.
    FrameSeen { person: bool, waving: bool, capturing: bool },
    /// A gesture was captured from the webcam; later episodes may use it.
    Captured { arm: String, seconds: [f32; 2], frames: usize, person_frames: usize },
    /// A webcam frame was not read: not a JPEG, too large, sent before the last was answered,
    /// or not an image; the session goes on. Every frame gets this or [`ToPage::FrameSeen`].
    FrameRefused { message: String },
    /// Something the page asked could not be done; the session goes on.
    Error { message: String },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointInfo {
    pub name: String,
    pub method: String,
    pub size: [u32; 2],
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepView {
    pub step: u32,
    /// The robot's RGB and depth as it saw them (PNG, base64).
    pub rgb_png: String,
    pub depth_png: String,
    /// x, z (m), yaw (degrees).
    pub robot: [f32; 3],
    /// The gesture shown with this observation, and what the angle rule would show
    /// (`shm_schema::gesture_kind`: 0 none, 1 referencing, 2 intervention).
    pub shown: u8,
    pub rule: u8,
    pub action: u8,
    pub probs: Vec<f32>,
    pub value: f32,
    pub distance: f32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeEnd {
    pub number: usize,
    pub steps: u32,
    /// At the first stop: success, SPL, distance to success (DTS, m).
    pub success: bool,
    pub spl: f64,
    pub dts: f64,
    /// Within the step limit, with unlimited stops.
    pub success_any_stop: bool,
    /// Where the session's record of this episode is.
    pub record: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_survive_a_round_trip() {
        let to_server = [
            ToServer::Start {
                program: "val:3".into(),
                checkpoint: 1,
                gesture: GestureSource::Webcam,
                interventions: Interventions::Person,
            },
            ToServer::Run { speed: 12.0 },
            ToServer::Pause,
            ToServer::Step,
            ToServer::Intervene,
            ToServer::CaptureGesture { seconds: 4.0 },
        ];
        for m in to_server {
            let text = serde_json::to_string(&m).unwrap();
            assert_eq!(serde_json::from_str::<ToServer>(&text).unwrap(), m, "{text}");
        }
        let to_page = [
            ToPage::FrameSeen { person: true, waving: false, capturing: true },
            ToPage::Error { message: "no".into() },
            ToPage::FrameRefused { message: "not a JPEG".into() },
            ToPage::Step(StepView {
                step: 2,
                rgb_png: "x".into(),
                depth_png: "y".into(),
                robot: [1.0, 2.0, 90.0],
                shown: 2,
                rule: 1,
                action: 3,
                probs: vec![0.25; 4],
                value: 0.5,
                distance: 1.2,
            }),
        ];
        for m in to_page {
            let text = serde_json::to_string(&m).unwrap();
            assert_eq!(serde_json::from_str::<ToPage>(&text).unwrap(), m, "{text}");
        }
    }

    #[test]
    fn the_page_may_leave_out_the_defaults_but_not_misname_a_field() {
        let m: ToServer = serde_json::from_str(r#"{"type":"start","program":"val:0","checkpoint":0}"#).unwrap();
        assert_eq!(
            m,
            ToServer::Start {
                program: "val:0".into(),
                checkpoint: 0,
                gesture: GestureSource::Program,
                interventions: Interventions::Rule
            }
        );
        assert!(serde_json::from_str::<ToServer>(r#"{"type":"start","programme":"val:0","checkpoint":0}"#).is_err());
    }
}
