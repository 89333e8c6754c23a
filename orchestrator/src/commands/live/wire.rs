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
    /// The gesture of the file last uploaded (a video, or a motion file; [`ToPage::Uploaded`]).
    Upload,
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
    /// A new episode on a dataset program (`program`, SPLIT:INDEX) or one the person placed
    /// (`placed`); `checkpoint` is an index into the server's list; `versus`, a second
    /// checkpoint run beside it on the same program, in lockstep (its own simulator, the same
    /// gesture, the same interventions' source).
    Start {
        #[serde(default)]
        program: Option<String>,
        #[serde(default)]
        placed: Option<Placement>,
        checkpoint: usize,
        #[serde(default)]
        versus: Option<usize>,
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
    /// A room of a split to place a program in: answered by [`ToPage::Room`].
    Room {
        split: String,
        room: String,
    },
}

/// A program the person places: a room of a split, a target in it (an object index, one of
/// [`RoomView`]'s), where the person stands (x, z; they face the target) and where the robot
/// starts (x, z, yaw in degrees). The person's referencing gesture is synthesised toward the
/// target as the dataset's are.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Placement {
    pub split: String,
    pub room: String,
    pub target: usize,
    pub person: [f32; 2],
    pub robot: [f32; 3],
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
    /// `rooms`: each split's rooms, where a program may be placed.
    Hello {
        checkpoints: Vec<CheckpointInfo>,
        splits: Vec<(String, usize)>,
        rooms: Vec<(String, Vec<String>)>,
        session: String,
    },
    /// A room to place a program in.
    Room(RoomView),
    /// An episode began: one robot a checkpoint, side by side.
    Episode {
        program: String,
        label: String,
        /// Side 0, and side 1 when two checkpoints are compared.
        sides: Vec<Side>,
        /// The room from above (PNG, base64) and where world points land on it.
        map_png: String,
        map_transform: MapTransform,
        target: [f32; 2],
        person: [f32; 2],
        gesture: GestureSource,
        interventions: Interventions,
        /// The person performing the referencing gesture the robots perceive.
        referencing: Film,
    },
    /// One step of one side: the observation its policy acted on and what it answered.
    Step(StepView),
    /// One side's episode ended.
    End(EpisodeEnd),
    /// A webcam frame was read: whether a person was found, and whether they are waving.
    FrameSeen { person: bool, waving: bool, capturing: bool },
    /// A gesture was captured from the webcam; later episodes may use it.
    Captured { arm: String, seconds: [f32; 2], frames: usize, person_frames: usize },
    /// An uploaded file was read into a gesture (`kind`: video or motion); later episodes may
    /// use it. A video says which arm gestured and in how many of its frames a person was seen.
    Uploaded { name: String, kind: String, arm: Option<String>, frames: usize, person_frames: usize },
    /// A webcam frame was not read: not a JPEG, too large, sent before the last was answered,
    /// or not an image; the session goes on. Every frame gets this or [`ToPage::FrameSeen`].
    FrameRefused { message: String },
    /// Something the page asked could not be done; the session goes on.
    Error { message: String },
    /// No session for this tab: the server runs as many as it may at once (`--max-sessions`).
    /// The socket closes after it.
    Full { message: String },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointInfo {
    pub name: String,
    pub method: String,
    pub size: [u32; 2],
}

/// One robot of an episode: the checkpoint acting, the number its record has, and the
/// intervention gesture its person shows it (each run's seed draws its own).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Side {
    pub number: usize,
    pub checkpoint: String,
    pub intervention: Film,
}

/// A gesture performed by the program's person, filmed: its frames tiled into one JPEG (base64)
/// of `columns` tiles a row, each `tile` pixels square, 30 a second.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Film {
    pub name: String,
    pub sheet_jpeg: String,
    pub tile: u32,
    pub columns: u32,
    pub frames: u32,
}

/// A room from above, where a program may be placed: its reachable targets.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoomView {
    pub split: String,
    pub room: String,
    pub map_png: String,
    pub map_transform: MapTransform,
    pub targets: Vec<TargetView>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TargetView {
    /// The object's index in the room.
    pub object: usize,
    pub name: String,
    /// x, z (m).
    pub at: [f32; 2],
}

/// One step as recorded (a line of `steps.jsonl`, `super::record`) and as the page sees it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    pub step: u32,
    /// x, z (m), yaw (degrees) where the robot observed.
    pub robot: [f32; 3],
    /// The gesture shown with the observation, and what the angle rule would show
    /// (`shm_schema::gesture_kind`: 0 none, 1 referencing, 2 intervention).
    pub shown: u8,
    pub rule: u8,
    pub action: u8,
    pub probs: Vec<f32>,
    pub value: f32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepView {
    /// Which robot (an index into [`ToPage::Episode`]'s `sides`).
    pub side: usize,
    #[serde(flatten)]
    pub record: StepRecord,
    /// The robot's RGB and depth as it saw them (PNG, base64).
    pub rgb_png: String,
    pub depth_png: String,
    /// Geodesic distance to the target (m).
    pub distance: f32,
}

/// How an episode ended (in its record's `episode.json`, `super::record`, and on the page).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Outcome {
    pub steps: u32,
    /// At the first stop: success, SPL, distance to success (DTS, m).
    pub success: bool,
    pub spl: f64,
    pub dts: f64,
    /// Within the step limit, with unlimited stops.
    pub success_any_stop: bool,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpisodeEnd {
    pub side: usize,
    pub number: usize,
    #[serde(flatten)]
    pub outcome: Outcome,
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
                program: Some("val:3".into()),
                placed: None,
                checkpoint: 1,
                versus: Some(0),
                gesture: GestureSource::Webcam,
                interventions: Interventions::Person,
            },
            ToServer::Run { speed: 12.0 },
            ToServer::Pause,
            ToServer::Step,
            ToServer::Intervene,
            ToServer::CaptureGesture { seconds: 4.0 },
            ToServer::Room { split: "val".into(), room: "FloorPlan21".into() },
            ToServer::Start {
                program: None,
                placed: Some(Placement {
                    split: "val".into(),
                    room: "FloorPlan21".into(),
                    target: 7,
                    person: [1.0, -0.5],
                    robot: [0.0, 1.0, 90.0],
                }),
                checkpoint: 0,
                versus: None,
                gesture: GestureSource::Upload,
                interventions: Interventions::Rule,
            },
        ];
        for m in to_server {
            let text = serde_json::to_string(&m).unwrap();
            assert_eq!(serde_json::from_str::<ToServer>(&text).unwrap(), m, "{text}");
        }
        let to_page = [
            ToPage::FrameSeen { person: true, waving: false, capturing: true },
            ToPage::Error { message: "no".into() },
            ToPage::Full { message: "all 4 in use".into() },
            ToPage::FrameRefused { message: "not a JPEG".into() },
            ToPage::Uploaded {
                name: "me.mp4".into(),
                kind: "video".into(),
                arm: Some("left".into()),
                frames: 90,
                person_frames: 88,
            },
            ToPage::End(EpisodeEnd {
                side: 1,
                number: 4,
                outcome: Outcome { steps: 17, success: true, spl: 0.75, dts: 0.0, success_any_stop: true },
                record: "runs/live/session-001/episode-004".into(),
            }),
            ToPage::Step(StepView {
                side: 1,
                record: StepRecord {
                    step: 2,
                    robot: [1.0, 2.0, 90.0],
                    shown: 2,
                    rule: 1,
                    action: 3,
                    probs: vec![0.25; 4],
                    value: 0.5,
                },
                rgb_png: "x".into(),
                depth_png: "y".into(),
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
                program: Some("val:0".into()),
                placed: None,
                checkpoint: 0,
                versus: None,
                gesture: GestureSource::Program,
                interventions: Interventions::Rule
            }
        );
        assert!(serde_json::from_str::<ToServer>(r#"{"type":"start","programme":"val:0","checkpoint":0}"#).is_err());
    }

    #[test]
    fn a_step_reads_as_its_record_with_the_pictures_beside() {
        let record = StepRecord {
            step: 4,
            robot: [0.5, -1.0, 270.0],
            shown: 1,
            rule: 0,
            action: 0,
            probs: vec![0.5, 0.25, 0.125, 0.125],
            value: -0.25,
        };
        let text = serde_json::to_string(&ToPage::Step(StepView {
            side: 0,
            record: record.clone(),
            rgb_png: "x".into(),
            depth_png: "y".into(),
            distance: 2.0,
        }))
        .unwrap();
        // the page reads the step's fields at the top level, as a line of steps.jsonl has them
        let flat: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(flat["type"], "step");
        assert_eq!(flat["shown"], 1);
        assert_eq!(serde_json::from_value::<StepRecord>(flat).unwrap(), record);
    }
}
