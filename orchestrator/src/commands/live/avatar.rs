//! The program's person performing a gesture the robots perceive, filmed for the page: the 100
//! frames (`gesture film`'s camera, 25° round from their front, nearer so that they fill the
//! frame) tiled into one JPEG, which the page plays at 30 frames a second while it is shown.

use image::{GenericImage, RgbImage};

use worker::gesture::{FRAMES, Motion};
use worker::humanoid::Humanoid;

use super::picture::jpeg_base64;
use super::wire::Film;

/// Pixels of a tile's side.
const TILE: u32 = 120;
const COLUMNS: u32 = 10;
/// Where the camera stands: degrees round from the person's front, metres away.
const ANGLE: f32 = 25.0;
const DISTANCE: f32 = 1.8;

/// `human` performing `motion`, filmed.
pub fn film(human: &Humanoid, motion: &Motion, name: &str) -> anyhow::Result<Film> {
    Ok(Film {
        name: name.into(),
        sheet_jpeg: jpeg_base64(&sheet(human, motion)?, 80)?,
        tile: TILE,
        columns: COLUMNS,
        frames: FRAMES as u32,
    })
}

/// The frames tiled, row by row.
fn sheet(human: &Humanoid, motion: &Motion) -> anyhow::Result<RgbImage> {
    let rows = (FRAMES as u32).div_ceil(COLUMNS);
    let mut sheet = RgbImage::new(TILE * COLUMNS, TILE * rows);
    crate::commands::gesture::film_frames(human, motion, ANGLE, DISTANCE, TILE, |t, img| {
        let t = t as u32;
        sheet.copy_from(&img, (t % COLUMNS) * TILE, (t / COLUMNS) * TILE)?;
        Ok(())
    })?;
    Ok(sheet)
}

#[cfg(test)]
mod tests {
    use base64::Engine;
    use image::GenericImageView;

    use super::*;

    #[test]
    fn a_film_holds_every_frame_and_the_person_moves_in_it() {
        let human = Humanoid::seeded(5);
        let wave = worker::gesture::intervention(1);
        let f = film(&human, &wave, "wave").unwrap();
        assert_eq!((f.frames, f.columns, f.tile), (100, 10, 120));
        assert!(base64::engine::general_purpose::STANDARD.decode(&f.sheet_jpeg).unwrap().starts_with(&[0xFF, 0xD8]));
        let sheet = sheet(&human, &wave).unwrap();
        assert_eq!(sheet.dimensions(), (1200, 1200));
        let tile = |t: u32| sheet.view((t % 10) * 120, (t / 10) * 120, 120, 120).to_image();
        let differ = |a: &RgbImage, b: &RgbImage| {
            a.pixels().zip(b.pixels()).filter(|(p, q)| p.0.iter().zip(q.0).any(|(x, y)| x.abs_diff(y) > 40)).count()
        };
        // the waving arm moves between the first frame and the middle one
        assert!(differ(&tile(0), &tile(50)) > 50, "the person did not move");
    }
}
