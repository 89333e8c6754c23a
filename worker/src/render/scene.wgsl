// GesTHOR-RS scene shader: instanced unit primitives → colour + (linear depth, instance id).
//
// Target 0 (Rgba8Unorm): display colour.
// Target 1 (R32Uint): depth16 << 16 | id, where depth16 = eye-space z in 0..10 m → 0..65535.
// Packing both into one integer target keeps the GL backend happy (it cannot render R32Float)
// and makes the readback one 4-byte word per pixel.
//
// Cost model: on a CPU rasteriser (lavapipe) every branch of a shader runs for every pixel
// (masked), so the fragment stage is branch-free and tiny. Lighting, the material's look and
// the display curve are evaluated per vertex; the fragment shader only adds the material's
// pattern (one or two sines and an optional tile grid) and packs depth and id.

struct ViewUniform {
    right: vec4<f32>,
    up: vec4<f32>,
    forward: vec4<f32>,
    eye: vec4<f32>, // xyz eye, w = pixel height at 1 m depth (metres)
    proj: vec4<f32>, // sx, sy, A, B: clip z = A - B * z_view (reversed Z), w = z_view
};

@group(0) @binding(0) var<uniform> view: ViewUniform;

// One part: model matrix columns (rotation × half extents) with the translation in w, the
// linear colour, and id | material << 16, as instance-rate vertex attributes. (Read from a
// storage buffer instead, lavapipe loads each word one SIMD lane at a time in a scalar
// loop: that cost more than all the vertex shader's arithmetic.)
struct Instance {
    col0: vec4<f32>,
    col1: vec4<f32>,
    col2: vec4<f32>,
    color: vec3<f32>,
    tag: u32,
};

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) col0: vec4<f32>,
    @location(3) col1: vec4<f32>,
    @location(4) col2: vec4<f32>,
    @location(5) color: vec3<f32>,
    @location(6) tag: u32,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    // lit colour in display space, before the pattern
    @location(0) color: vec3<f32>,
    // (stripe phase, wobble phase, tile grid u, tile grid v): all linear in position
    @location(1) pattern: vec4<f32>,
    @location(2) z_view: f32,
    // (stripe amplitude, wobble amplitude, pattern fade per metre of depth, grid darkening)
    @location(3) @interpolate(flat) look: vec4<f32>,
    @location(4) @interpolate(flat) tag: u32,
};

const SUN_DIR: vec3<f32> = vec3<f32>(0.36, 0.80, -0.48);
const SUN: vec3<f32> = vec3<f32>(0.55, 0.53, 0.50);
const SKY: vec3<f32> = vec3<f32>(0.62, 0.64, 0.68);
const GROUND: vec3<f32> = vec3<f32>(0.30, 0.28, 0.26);
const TILE_PERIOD: f32 = 0.3;
// grout half width in grid units (6 mm)
const GROUT: f32 = 0.02;

// How a material looks; indexed by geometry::Material.
struct Look {
    stripe: vec3<f32>,    // stripe frequency over the local position (x along the longest side)
    wobble: vec3<f32>,    // frequency of the phase wobble
    amp: vec2<f32>,       // stripe amplitude, wobble amplitude
    grid: f32,            // tile grid darkening
    sun: f32,             // scale of direct light
    ambient: f32,         // scale of ambient light
    emit: f32,            // share of the base colour that glows unlit
    spec: f32,            // highlight strength
    sky_mix: f32,         // reflection of the sky (glass)
};

fn look_of(material: u32) -> Look {
    var l = Look(vec3<f32>(0.0), vec3<f32>(0.0), vec2<f32>(0.0), 0.0, 1.0, 1.0, 0.0, 0.0, 0.0);
    switch material {
        case 1u: { // wood: grain along the longest side, wavy
            l.stripe = vec3<f32>(0.0, 60.0, 60.0);
            l.wobble = vec3<f32>(4.0, 15.0, 0.0);
            l.amp = vec2<f32>(0.08, 2.5);
        }
        case 2u: { // fabric: a coarse weave, soft light
            l.stripe = vec3<f32>(120.0, 0.0, 0.0);
            l.wobble = vec3<f32>(0.0, 120.0, 120.0);
            l.amp = vec2<f32>(0.05, 1.5);
            l.sun = 0.85;
        }
        case 3u: { // metal
            l.spec = 0.5;
            l.sun = 0.8;
        }
        case 4u: { // glass
            l.sky_mix = 0.3;
            l.spec = 0.7;
        }
        case 5u: { // tile: grout lines
            l.grid = 0.3;
            l.spec = 0.1;
        }
        case 6u: { // screen: dark, slightly glowing
            l.sun = 0.4;
            l.ambient = 0.4;
            l.emit = 0.6;
            l.spec = 0.25;
        }
        case 7u: { // paper: flat and bright
            l.ambient = 1.08;
        }
        case 8u: { // skin: soft wrap-around light
            l.sun = 0.75;
            l.ambient = 1.1;
        }
        case 9u: { // emissive: unlit
            l.sun = 0.0;
            l.ambient = 0.0;
            l.emit = 1.0;
        }
        default: {}
    }
    return l;
}

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    let inst = Instance(v.col0, v.col1, v.col2, v.color, v.tag);
    let a0 = inst.col0.xyz;
    let a1 = inst.col1.xyz;
    let a2 = inst.col2.xyz;
    let t = vec3<f32>(inst.col0.w, inst.col1.w, inst.col2.w);
    let world = a0 * v.position.x + a1 * v.position.y + a2 * v.position.z + t;
    // inverse transpose of (R·S) is R·S⁻¹: column i divided by its squared length
    let l2 = vec3<f32>(dot(a0, a0), dot(a1, a1), dot(a2, a2));
    let n = normalize(a0 * (v.normal.x / l2.x) + a1 * (v.normal.y / l2.y) + a2 * (v.normal.z / l2.z));

    let d = world - view.eye.xyz;
    let zv = dot(d, view.forward.xyz);
    var out: VertexOut;
    out.clip = vec4<f32>(dot(d, view.right.xyz) * view.proj.x, dot(d, view.up.xyz) * view.proj.y,
                         view.proj.z - zv * view.proj.w, zv);
    out.z_view = zv;

    let material = inst.tag >> 16u;
    let look = look_of(material);

    // lighting: hemisphere ambient + sun + a Blinn highlight for shiny materials
    let base = mix(inst.color, SKY, look.sky_mix);
    let ambient = mix(GROUND, SKY, n.y * 0.5 + 0.5) * look.ambient;
    let sun = SUN * (max(dot(n, SUN_DIR), 0.0) * look.sun);
    let h = normalize(normalize(-d) + SUN_DIR);
    let s = max(dot(n, h), 0.0);
    let s4 = (s * s) * (s * s);
    let highlight = look.spec * 0.5 * (s4 * s4) * (s4 * s4);
    let lit = base * (ambient + sun) + inst.color * look.emit + vec3<f32>(highlight);
    // linear → display (gamma 2.2, the sRGB curve within a few codes)
    out.color = pow(clamp(lit, vec3<f32>(0.0), vec3<f32>(1.0)), vec3<f32>(1.0 / 2.2));

    // pattern phases: in the part's frame (metres), permuted so x runs along its longest side
    let he = sqrt(l2);
    let p0 = v.position * he;
    var p = p0;
    if he.y >= he.x && he.y >= he.z {
        p = p0.yxz;
    } else if he.z >= he.x {
        p = p0.zyx;
    }
    // tile grid in world metres on the two axes the face spans
    let an = abs(n);
    var g = world.xz;
    if an.x > an.y && an.x > an.z {
        g = world.zy;
    } else if an.z > an.y {
        g = world.xy;
    }
    out.pattern = vec4<f32>(dot(p, look.stripe), dot(p, look.wobble), g / TILE_PERIOD);
    // Patterns finer than a few pixels alias into noise: fade them out with depth. Full
    // strength while a stripe period spans 8+ pixels (grout: while a pixel is under 8 mm),
    // gone by half that; `fade` is the slope of 2 − z·fade.
    let stripe_per_metre = select(length(look.stripe) / 0.8, 1.0 / 0.008, look.grid > 0.0);
    out.look = vec4<f32>(look.amp, stripe_per_metre * view.eye.w, look.grid);
    out.tag = inst.tag;
    return out;
}

struct FragmentOut {
    @location(0) color: vec4<f32>,
    @location(1) info: u32,
};

// A triangle wave with the period and range of sin(x), far cheaper per pixel.
fn wave(x: f32) -> f32 {
    return abs(fract(x * 0.15915494 + 0.25) - 0.5) * 4.0 - 1.0;
}

@fragment
fn fs_main(in: VertexOut) -> FragmentOut {
    let fade = clamp(2.0 - in.z_view * in.look.z, 0.0, 1.0);
    let stripe = 1.0 + in.look.x * fade * wave(in.pattern.x + in.look.y * wave(in.pattern.y));
    let f = abs(fract(in.pattern.zw + 0.5) - 0.5);
    let grout = 1.0 - select(0.0, in.look.w * fade, min(f.x, f.y) < GROUT);
    let depth = u32(clamp(in.z_view * 0.1, 0.0, 1.0) * 65535.0 + 0.5);
    var out: FragmentOut;
    out.color = vec4<f32>(in.color * (stripe * grout), 1.0);
    out.info = (depth << 16u) | (in.tag & 0xffffu);
    return out;
}
