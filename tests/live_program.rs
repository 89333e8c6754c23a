//! `orchestrator live` at the socket, for what a person brings of their own: a program they place
//! (a room, a target, where the person and the robot stand) and a gesture they upload (a motion
//! file, or a video of themselves); and the person performing the perceived gestures, filmed;
//! then in a real browser over HTTPS: a program placed by clicking the map, the person's film
//! playing.

use std::path::{Path, PathBuf};
use std::process::Command;

use base64::Engine;
use futures_util::SinkExt;
use gesthor_tests::{bin, capture_ready, dataset};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use worker::dataset::{Dataset, Verify};
use worker::gesture::Motion;
use worker::scene::Split;

use crate::live::{
    Driver, Server, browser_ready, chromium, click, filmed_y4m, http_response, next, page, status, wait_page,
};

/// A POST on loopback: the status code and the body.
fn http_post(port: u16, path: &str, body: &[u8]) -> (u16, String) {
    let response = http_response(port, "POST", path, body);
    (status(&response).parse().unwrap_or(0), crate::live::body(response))
}

async fn send(ws: &mut crate::live::Socket, m: Value) {
    ws.send(Message::Text(m.to_string().into())).await.unwrap();
}

/// Runs an episode to its end; its record's folder.
async fn run_to_end(ws: &mut crate::live::Socket) -> PathBuf {
    send(ws, json!({"type": "run", "speed": 60})).await;
    loop {
        let m = next(ws).await;
        match m["type"].as_str() {
            Some("step") => continue,
            Some("end") => return PathBuf::from(m["record"].as_str().unwrap()),
            _ => panic!("{m}"),
        }
    }
}

fn replays(record: &Path) {
    let o = Command::new(bin("orchestrator")).args(["live", "replay", &record.display().to_string()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("the same path"));
}

/// The one program of an episode's record, and its gesture.
fn recorded(record: &Path) -> (worker::program::Program, Motion) {
    let ds = Dataset::open(&record.join("dataset"), Verify::Quick).unwrap();
    let file = ds.require(Split::Val).unwrap();
    let p = worker::program::Program::from_record(0, &file.record(0)).unwrap();
    (p, Motion::from_flat(&file.motion(0)).unwrap())
}

/// A film's sheet: a JPEG's width and height (its baseline frame header, SOF0).
fn sheet_size(film: &Value) -> (u32, u32) {
    let jpeg = base64::engine::general_purpose::STANDARD.decode(film["sheet_jpeg"].as_str().unwrap()).unwrap();
    assert!(jpeg.starts_with(&[0xFF, 0xD8]), "not a JPEG");
    let sof = jpeg.windows(2).position(|w| w == [0xFF, 0xC0]).expect("a baseline JPEG");
    let be = |i: usize| u32::from(jpeg[sof + i]) << 8 | u32::from(jpeg[sof + i + 1]);
    (be(7), be(5))
}

#[test]
fn a_person_places_a_program_and_uploads_their_gesture() {
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let server = Server::start(&tmp.path().join("live"), &["--listen", "127.0.0.1:0"]);
    // val:1's room, target and places, as the person would click them
    let ds = Dataset::open(&dataset(), Verify::Quick).unwrap();
    let base = ds.program(Split::Val, 1).unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (placed_record, upload_record) = rt.block_on(async {
        let ws_url = format!("ws://127.0.0.1:{}{}", server.port, server.at("/ws"));
        let (mut ws, _) = tokio_tungstenite::connect_async(ws_url).await.unwrap();
        let hello = next(&mut ws).await;
        let session = hello["session"].as_str().unwrap().to_string();
        let val_rooms = hello["rooms"].as_array().unwrap().iter().find(|r| r[0] == "val").unwrap()[1].clone();
        assert!(val_rooms.as_array().unwrap().contains(&json!(base.scene)), "{val_rooms}");

        // the room from above, with its targets
        send(&mut ws, json!({"type": "room", "split": "val", "room": base.scene})).await;
        let room = next(&mut ws).await;
        assert_eq!(room["type"], "room", "{room}");
        let targets = room["targets"].as_array().unwrap();
        assert!(targets.iter().any(|t| t["object"] == base.target_object), "{room}");

        // placed where val:1's person and robot stand; the person faces the target
        let placed = |robot: [f32; 3]| {
            json!({"type": "start", "checkpoint": 0, "placed": {
                "split": "val", "room": base.scene, "target": base.target_object,
                "person": [base.human_pos[0], base.human_pos[2]], "robot": robot}})
        };
        send(&mut ws, placed([40.0, 40.0, 0.0])).await;
        let e = next(&mut ws).await;
        assert!(e["type"] == "error" && e["message"].as_str().unwrap().contains("outside the room"), "{e}");
        send(&mut ws, placed([base.robot_pos[0], base.robot_pos[2], base.robot_yaw])).await;
        let episode = next(&mut ws).await;
        assert_eq!(episode["type"], "episode", "{episode}");
        assert!(episode["label"].as_str().unwrap().contains(&base.scene), "{}", episode["label"]);
        // the person performing the referencing gesture and this robot's intervention gesture
        assert_eq!(sheet_size(&episode["referencing"]), (1200, 1200));
        assert_eq!(sheet_size(&episode["sides"][0]["intervention"]), (1200, 1200));
        let placed_record = run_to_end(&mut ws).await;

        // a motion file: the session holds it, and an episode performs it as recorded
        let wave = worker::gesture::intervention(1);
        let csv = tmp.path().join("wave.csv");
        worker::gesture::motion::write_csv(&csv, &wave).unwrap();
        let upload = |name: &str| server.at(&format!("/upload?session={session}&name={name}"));
        let (status, body) = http_post(server.port, &upload("wave.csv"), &std::fs::read(&csv).unwrap());
        assert_eq!(status, 202, "{body}");
        let told = next(&mut ws).await;
        assert_eq!((told["type"].as_str(), told["kind"].as_str()), (Some("uploaded"), Some("motion")), "{told}");
        send(&mut ws, json!({"type": "start", "program": "val:1", "checkpoint": 0, "gesture": "upload"})).await;
        assert_eq!(next(&mut ws).await["type"], "episode");
        let upload_record = run_to_end(&mut ws).await;

        // a file that is not a motion gets one error naming it; a session that is not open, a 404
        let (status, _) = http_post(server.port, &upload("notes.csv"), b"not a motion");
        assert_eq!(status, 202);
        let e = next(&mut ws).await;
        assert!(e["type"] == "error" && e["message"].as_str().unwrap().contains("notes.csv"), "{e}");
        assert_eq!(http_post(server.port, &server.at("/upload?session=session-999&name=x.csv"), b"1").0, 404);

        // a video of the person gesturing (our avatar, filmed), read as `gesture capture` reads one
        if capture_ready() {
            let y4m = filmed_y4m(tmp.path(), None);
            let (status, body) = http_post(server.port, &upload("me.y4m"), &std::fs::read(&y4m).unwrap());
            assert_eq!(status, 202, "{body}");
            let told = next(&mut ws).await;
            assert_eq!((told["type"].as_str(), told["kind"].as_str()), (Some("uploaded"), Some("video")), "{told}");
            assert!(told["person_frames"].as_u64().unwrap() * 2 >= told["frames"].as_u64().unwrap(), "{told}");
        }
        ws.close(None).await.unwrap();
        (placed_record, upload_record)
    });

    // the placed program is recorded as placed, and replays
    let (p, _) = recorded(&placed_record);
    assert_eq!((p.scene.as_str(), p.target_object), (base.scene.as_str(), base.target_object));
    assert_eq!(p.human_pos, base.human_pos);
    let moved = ((p.robot_pos[0] - base.robot_pos[0]).powi(2) + (p.robot_pos[2] - base.robot_pos[2]).powi(2)).sqrt();
    assert!(moved < 0.2 && p.robot_yaw == base.robot_yaw, "{:?} {} for {:?}", p.robot_pos, p.robot_yaw, base.robot_pos);
    replays(&placed_record);
    // the uploaded motion is the episode's gesture (to the dataset's half floats), and replays
    let (_, m) = recorded(&upload_record);
    let wave = worker::gesture::intervention(1);
    let worst = m.as_flat().iter().zip(wave.as_flat()).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-2, "{worst}");
    replays(&upload_record);
    assert!(tmp.path().join("live").read_dir().unwrap().flatten().any(|s| s.path().join("uploads/wave.csv").is_file()));
}

/// Clicks the map where world point (x, z) is drawn, as a person's click lands (`map_transform`
/// maps a world point to the map picture's pixel; the canvas may be shown scaled).
fn click_map(x: f32, z: f32) -> String {
    format!(
        "(() => {{ const [a, b, c, d, e, f] = window.live.room.map_transform, m = document.getElementById('map'); \
         const box = m.getBoundingClientRect(), u = a * {x} + b * {z} + c, v = d * {x} + e * {z} + f; \
         m.dispatchEvent(new MouseEvent('click', {{ bubbles: true, clientX: box.left + u * box.width / m.width, \
         clientY: box.top + v * box.height / m.height }})); return true; }})()"
    )
}

#[test]
fn a_program_placed_on_the_map_runs_in_a_real_browser_over_https_with_the_person_gesturing_beside_it() {
    if !browser_ready() {
        return;
    }
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let cam = filmed_y4m(tmp.path(), None);
    // over HTTPS, the page's socket over wss:// (the certificate made here, which Chromium is
    // told to accept; the pinned check of a certificate is the HTTPS test's, tests/live.rs)
    let key = rcgen::KeyPair::generate().unwrap();
    let cert = rcgen::CertificateParams::new(vec!["localhost".to_string()]).unwrap().self_signed(&key).unwrap();
    let (cert_pem, key_pem) = (tmp.path().join("cert.pem"), tmp.path().join("key.pem"));
    std::fs::write(&cert_pem, cert.pem()).unwrap();
    std::fs::write(&key_pem, key.serialize_pem()).unwrap();
    let (c, k) = (cert_pem.display().to_string(), key_pem.display().to_string());
    let tls = ["--listen", "127.0.0.1:0", "--tls-cert", &c, "--tls-key", &k];
    let server = Server::start(&tmp.path().join("live"), &tls);
    assert!(server.url.starts_with("https://"), "{}", server.url);
    let driver = Driver::start();
    let base = Dataset::open(&dataset(), Verify::Quick).unwrap().program(Split::Val, 1).unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let record = rt.block_on(async {
        let c = chromium(&driver, &cam, &tmp.path().join("profile"), &["--ignore-certificate-errors"]).await;
        c.goto(&server.url).await.unwrap();
        wait_page(&c, "the page never got its session", "window.live && window.live.session").await;
        let choose = |id: &str, value: &str| {
            format!("(() => {{ const s = document.getElementById('{id}'); s.value = '{value}'; s.dispatchEvent(new Event('change')); return s.value == '{value}'; }})()")
        };
        assert_eq!(page(&c, &choose("program-kind", "placed")).await, json!(true));
        assert_eq!(page(&c, &choose("room", &base.scene)).await, json!(true), "{} is not offered", base.scene);
        let room = format!("window.live.room && window.live.room.room == '{}'", base.scene);
        wait_page(&c, "the room never came", &room).await;
        assert_eq!(page(&c, &choose("target", &base.target_object.to_string())).await, json!(true));
        // the person first, then the robot (the page moves on to it), then its facing
        page(&c, &click_map(base.human_pos[0], base.human_pos[2])).await;
        assert_eq!(page(&c, "document.getElementById('placing').value").await, json!("robot"));
        page(&c, &click_map(base.robot_pos[0], base.robot_pos[2])).await;
        page(&c, &format!("(document.getElementById('robot-yaw').value = '{}', true)", base.robot_yaw)).await;
        click(&c, "start").await;
        let label = wait_page(&c, "the placed program did not start", "window.live.episode && window.live.episode.label").await;
        assert!(label.as_str().unwrap().contains(&format!("{} placed →", base.scene)), "{label}");

        // the person performs the gesture the robot perceives: the film plays, frame after frame
        click(&c, "step").await;
        wait_page(&c, "no first step", "window.live.sides[0].steps == 1").await;
        let film = "(() => { const d = document.querySelector('#side-0 .avatar').getContext('2d').getImageData(0, 0, 120, 120).data; \
                    let h = 0; for (let i = 0; i < d.length; i += 4) h = (h * 31 + d[i] + 7 * d[i + 1]) % 1000003; return h; })()";
        let first = wait_page(&c, "the person's film was never drawn", &format!("{film} != 0 && {film}")).await;
        wait_page(&c, "the person's film stands still", &format!("{film} != {first}")).await;
        page(&c, "(document.getElementById('speed').value = '30', true)").await;
        click(&c, "run").await;
        wait_page(&c, "the episode never ended", "window.live.ended").await;
        assert_eq!(page(&c, "window.live.errors").await, json!([]), "the page's errors");
        let end = page(&c, "window.live.sides[0].end").await;
        c.close().await.unwrap();
        PathBuf::from(end["record"].as_str().unwrap())
    });
    // where the clicks landed: within a few pixels of the map (60 a metre, the canvas scaled)
    let (p, _) = recorded(&record);
    assert_eq!((p.scene.as_str(), p.target_object), (base.scene.as_str(), base.target_object));
    let off = |a: [f32; 3], b: [f32; 3]| ((a[0] - b[0]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    assert!(
        off(p.human_pos, base.human_pos) < 0.06,
        "the person at {:?}, clicked at {:?}",
        p.human_pos,
        base.human_pos
    );
    assert!(off(p.robot_pos, base.robot_pos) < 0.2, "the robot at {:?}, clicked at {:?}", p.robot_pos, base.robot_pos);
    assert_eq!(p.robot_yaw, base.robot_yaw);
    replays(&record);
}
