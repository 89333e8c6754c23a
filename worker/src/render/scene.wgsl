// GesTHOR-RS scene shader: instanced unit primitives → colour + (linear depth, instance id).
//
// Target 0 (Rgba8Unorm): display colour.
// Target 1 (R32Uint): depth16 << 16 | id, where depth16 = eye-space z in 0..10 m → 0..65535.
// Packing both into one integer target keeps the GL backend happy (it cannot render R32Float)
// and makes the readback one 4-byte word per pixel.

struct ViewUniform {
    right: vec4<f32>,
    up: vec4<f32>,
    forward: vec4<f32>,
    eye: vec4<f32>,
    proj: vec4<f32>, // sx, sy, A, B: clip z = A - B * z_view (reversed Z), w = z_view
};

@group(0) @binding(0) var<uniform> view: ViewUniform;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    // model matrix columns (rotation × half extents), translation in w
    @location(2) col0: vec4<f32>,
    @location(3) col1: vec4<f32>,
    @location(4) col2: vec4<f32>,
    @location(5) color: vec3<f32>,
    // id | material << 16
    @location(6) tag: u32,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    // position in the part's own frame, in metres, x along its longest side (patterns)
    @location(1) local: vec3<f32>,
    @location(2) world: vec3<f32>,
    @location(3) @interpolate(flat) color: vec3<f32>,
    @location(4) @interpolate(flat) tag: u32,
};

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    let a0 = v.col0.xyz;
    let a1 = v.col1.xyz;
    let a2 = v.col2.xyz;
    let t = vec3<f32>(v.col0.w, v.col1.w, v.col2.w);
    let world = a0 * v.position.x + a1 * v.position.y + a2 * v.position.z + t;
    // inverse transpose of (R·S) is R·S⁻¹: column i divided by its squared length
    let l0 = dot(a0, a0);
    let l1 = dot(a1, a1);
    let l2 = dot(a2, a2);
    let n = a0 * (v.normal.x / l0) + a1 * (v.normal.y / l1) + a2 * (v.normal.z / l2);

    let d = world - view.eye.xyz;
    let zv = dot(d, view.forward.xyz);
    var out: VertexOut;
    out.clip = vec4<f32>(dot(d, view.right.xyz) * view.proj.x, dot(d, view.up.xyz) * view.proj.y,
                         view.proj.z - zv * view.proj.w, zv);
    out.normal = n;
    // local position in metres, permuted so that x runs along the longest side (wood grain)
    let h = sqrt(vec3<f32>(l0, l1, l2));
    let p = v.position * h;
    if h.y >= h.x && h.y >= h.z {
        out.local = p.yxz;
    } else if h.z >= h.x {
        out.local = p.zyx;
    } else {
        out.local = p;
    }
    out.world = world;
    out.color = v.color;
    out.tag = v.tag;
    return out;
}

struct FragmentOut {
    @location(0) color: vec4<f32>,
    @location(1) info: u32,
};

const MATTE: u32 = 0u;
const WOOD: u32 = 1u;
const FABRIC: u32 = 2u;
const METAL: u32 = 3u;
const GLASS: u32 = 4u;
const TILE: u32 = 5u;
const SCREEN: u32 = 6u;
const PAPER: u32 = 7u;
const SKIN: u32 = 8u;
const EMISSIVE: u32 = 9u;

const SUN_DIR: vec3<f32> = vec3<f32>(0.36, 0.80, -0.48);
const SUN: vec3<f32> = vec3<f32>(0.55, 0.53, 0.50);
const SKY: vec3<f32> = vec3<f32>(0.62, 0.64, 0.68);
const GROUND: vec3<f32> = vec3<f32>(0.30, 0.28, 0.26);

// Darkens thin lines every `period` metres along the two axes a face spans.
fn grid(p: vec3<f32>, n: vec3<f32>, period: f32, width: f32) -> f32 {
    let f = abs(fract(p / period + 0.5) - 0.5) * period; // distance to the nearest line
    let on_face = step(abs(n), vec3<f32>(0.7)); // ignore the axis the face looks along
    let line = (1.0 - step(vec3<f32>(width), f)) * on_face;
    return 1.0 - 0.35 * max(max(line.x, line.y), line.z);
}

@fragment
fn fs_main(in: VertexOut) -> FragmentOut {
    let material = in.tag >> 16u;
    let n = normalize(in.normal);
    var base = in.color;
    var sun = max(dot(n, SUN_DIR), 0.0);
    var ambient = mix(GROUND, SKY, n.y * 0.5 + 0.5);
    var emit = vec3<f32>(0.0);
    var spec = 0.0;

    switch material {
        case WOOD: {
            // grain along the part's longest side (local x), with a slow wobble
            let p = in.local;
            let g = sin((p.y + p.z) * 90.0 + sin(p.x * 4.0 + p.y * 20.0) * 3.0);
            base = base * (0.9 + 0.1 * g);
        }
        case FABRIC: {
            let p = in.local * 260.0;
            let w = sin(p.x) * sin(p.y + p.z) + sin(p.z) * sin(p.y);
            base = base * (0.93 + 0.05 * w);
            sun = sun * 0.85;
        }
        case TILE: {
            base = base * grid(in.world, n, 0.3, 0.006);
            spec = 0.15;
        }
        case METAL: {
            spec = 0.6;
        }
        case GLASS: {
            base = mix(base, SKY, 0.3);
            spec = 0.8;
        }
        case SCREEN: {
            emit = base * 0.6;
            base = base * 0.4;
            spec = 0.3;
        }
        case PAPER: {
            ambient = ambient * 1.08;
        }
        case SKIN: {
            sun = sun * 0.7 + 0.15; // soft wrap-around light
        }
        case EMISSIVE: {
            emit = base;
            base = vec3<f32>(0.0);
        }
        default: {}
    }

    var lit = base * (ambient + SUN * sun) + emit;
    if spec > 0.0 {
        let to_eye = normalize(view.eye.xyz - in.world);
        let h = normalize(to_eye + SUN_DIR);
        let s = max(dot(n, h), 0.0);
        let s2 = s * s;
        let s4 = s2 * s2;
        let s16 = s4 * s4 * s4 * s4;
        lit = lit + vec3<f32>(spec * s16 * 0.5);
    }
    // linear → display (gamma 2.2, the sRGB curve within a few codes)
    let display = pow(clamp(lit, vec3<f32>(0.0), vec3<f32>(1.0)), vec3<f32>(1.0 / 2.2));

    let zv = dot(in.world - view.eye.xyz, view.forward.xyz);
    let depth = u32(clamp(zv * 0.1, 0.0, 1.0) * 65535.0 + 0.5);
    var out: FragmentOut;
    out.color = vec4<f32>(display, 1.0);
    out.info = (depth << 16u) | (in.tag & 0xffffu);
    return out;
}
