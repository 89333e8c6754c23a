//! What a renderer is asked for: image size, field of view and views per submission.

use super::error::RenderError;
use crate::camera::Intrinsics;

/// Image size, field of view and how many views go into one GPU submission.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderConfig {
    pub width: u32,
    pub height: u32,
    /// Vertical field of view in degrees; the horizontal one follows from the aspect ratio
    /// (equal for the square 224×224 images of §3.2.2).
    pub fov_deg: f32,
    /// Views rendered per submit and read back with one map. More amortises the fixed cost
    /// of a submission (large on a GPU); each slot holds a colour, an info and a depth layer.
    pub max_views_per_submit: usize,
}

impl Default for RenderConfig {
    /// The robot's camera of §3.2.2: 224×224, 90° field of view.
    fn default() -> Self {
        RenderConfig { width: 224, height: 224, fov_deg: 90.0, max_views_per_submit: 16 }
    }
}

impl RenderConfig {
    /// Image size and field of view, as the camera module speaks of them.
    pub fn intrinsics(&self) -> Intrinsics {
        Intrinsics { width: self.width, height: self.height, fov_deg: self.fov_deg }
    }

    pub(super) fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::Config(m));
        if self.width == 0 || self.height == 0 || self.width > 8192 || self.height > 8192 {
            return bad(format!("image size {}×{} must be between 1 and 8192 pixels", self.width, self.height));
        }
        if !(self.fov_deg.is_finite() && self.fov_deg > 1.0 && self.fov_deg < 179.0) {
            return bad(format!("fov_deg {} must be between 1 and 179 degrees", self.fov_deg));
        }
        if self.max_views_per_submit == 0 {
            return bad("max_views_per_submit must be at least 1".into());
        }
        Ok(())
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}
