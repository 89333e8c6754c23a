//! A view to render and where its images go: the renderer's inputs and outputs per view.

use super::scenes::SceneHandle;
use crate::camera::Camera;
use crate::geometry::Part;

/// One view to render: a scene, a camera and the parts that move this frame (the person).
#[derive(Clone, Copy, Debug)]
pub struct View<'a> {
    pub scene: SceneHandle,
    pub camera: Camera,
    pub dynamic: &'a [Part],
}

/// Where one view's images go. Sizes: `rgb` width·height·3, `depth` and `ids` width·height.
#[derive(Debug)]
pub struct ViewOut<'a> {
    /// Row-major, top row first, RGB.
    pub rgb: &'a mut [u8],
    /// Eye-space depth, 0..10 m → 0..65535 (saturating; nothing = 65535).
    pub depth: &'a mut [u16],
    /// `Part::id` of the visible surface, 0 where nothing is.
    pub ids: Option<&'a mut [u16]>,
}

impl<'a> ViewOut<'a> {
    /// Cuts buffers holding several views back to back (`pixels` each) into one output per view.
    pub fn split(rgb: &'a mut [u8], depth: &'a mut [u16], ids: &'a mut [u16], pixels: usize) -> Vec<ViewOut<'a>> {
        rgb.chunks_exact_mut(pixels * 3)
            .zip(depth.chunks_exact_mut(pixels))
            .zip(ids.chunks_exact_mut(pixels))
            .map(|((rgb, depth), ids)| ViewOut { rgb, depth, ids: Some(ids) })
            .collect()
    }
}

/// Number of pixels showing instance `id`.
pub fn count_id(ids: &[u16], id: u16) -> u32 {
    ids.iter().filter(|&&v| v == id).count() as u32
}
