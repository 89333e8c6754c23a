//! The GesTHOR simulator as a library, in the stages of the dissertation's system:
//! `scene` (data) → `physics` (collision queries) → `nav` (grid, geodesic, expert) →
//! `task` (success, reward, stops) → `render` (RGB, depth, ids) and
//! `humanoid` / `gesture` (motion → skeleton → avatar). `env` composes them.

pub mod config;
pub mod geometry;
pub mod render;
pub mod scene;
pub mod util;
