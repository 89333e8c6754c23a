//! The GesTHOR simulator as a library, in the stages of the dissertation's system:
//! `scene` (data) → `physics` (collision queries) → `nav` (grid, geodesic, expert) →
//! `task` (success, reward, stops) → `render` (RGB, depth, ids) and
//! `humanoid` / `gesture` (motion → skeleton → avatar). `env` composes them.

pub mod camera;
pub mod dataset;
pub mod env;
pub mod geometry;
pub mod gesture;
pub mod humanoid;
pub mod nav;
pub mod physics;
pub mod program;
pub mod render;
pub mod robot;
pub mod scene;
pub mod shortest_path;
pub mod task;
pub mod visibility;
