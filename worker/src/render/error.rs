//! What can go wrong while setting up the renderer or rendering.

/// What can go wrong while setting up or rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no wgpu adapter found on backends {0}: install a Vulkan driver (Mesa lavapipe: `apt-get install mesa-vulkan-drivers`) or an OpenGL ES driver"
    )]
    NoAdapter(String),
    #[error("GESTHOR_WGPU_BACKEND={0:?}: expected `vulkan` or `gl`")]
    BadBackend(String),
    #[error("GESTHOR_RENDER_LANES={0:?}: expected a whole number from 1 to 16")]
    BadLanes(String),
    #[error("cannot open a device on adapter {adapter}: {message}")]
    Device { adapter: String, message: String },
    #[error("render config: {0}")]
    Config(String),
    #[error("{views} views but {outputs} outputs: give one output per view")]
    OutputCount { views: usize, outputs: usize },
    #[error("output {index}: `{field}` holds {got} values, expected {expected}")]
    OutputSize { index: usize, field: &'static str, got: usize, expected: usize },
    #[error("view {index}: the scene handle was released or never uploaded")]
    UnknownScene { index: usize },
    #[error("reading the rendered frames back failed: {0}")]
    Readback(String),
    #[error("frames on the device: {0}")]
    Export(String),
}
