// kilotouch microscope scene: a bright-field look of micro-beads.
//
// One full-rect triangle; the fragment shader evaluates, per pixel, the
// intensity of a bright-field image of transparent spheres: a dark ring at
// the rim (light refracted out of the objective's aperture), a bright focus
// spot at the centre (the bead acts as a ball lens), faint Airy-like rings
// outside that decay with distance, all widened by the defocus blur; then
// per-frame camera noise and the trap marker.

struct Uniforms {
    // centre x, y (µm), half width, half height of the view (µm)
    view: vec4<f32>,
    // blur (µm), noise amplitude, frame seed, number of beads
    params: vec4<f32>,
    // trap x, y (µm), marker radius (µm), emergency stop (0/1)
    trap: vec4<f32>,
    // x, y, radius (µm), kind (0 obstacle, 1 manipulated bead)
    beads: array<vec4<f32>, 16>,
};

@group(0) @binding(0) var<uniform> u: Uniforms;

struct VsOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> VsOut {
    // A triangle covering the viewport: (-1,-1), (3,-1), (-1,3).
    let x = f32((i << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(i & 2u) * 2.0 - 1.0;
    var o: VsOut;
    o.pos = vec4<f32>(x, y, 0.0, 1.0);
    o.uv = vec2<f32>(x * 0.5 + 0.5, y * 0.5 + 0.5);
    return o;
}

fn hash(p: vec2<f32>, seed: f32) -> f32 {
    let q = vec3<f32>(p, seed);
    var h = fract(q * vec3<f32>(0.1031, 0.1030, 0.0973));
    h = h + dot(h, h.yzx + 33.33);
    return fract((h.x + h.y) * h.z);
}

fn bead_intensity(p: vec2<f32>, b: vec4<f32>, blur: f32) -> f32 {
    let d = length(p - b.xy);
    let r = b.z;
    let edge = d - r;
    let soft = 1.0 / (1.0 + 2.0 * blur);
    let w = 0.18 * r + blur;
    // dark rim
    var i = -0.62 * soft * exp(-(edge * edge) / (w * w));
    // darker, slightly grey body
    i = i - 0.18 * soft * smoothstep(0.15 * r, -0.15 * r, edge);
    // bright focus spot
    let c = 0.28 * r + 0.5 * blur;
    i = i + 0.55 * soft * exp(-(d * d) / (c * c));
    // Airy-like rings outside the rim
    if (edge > 0.0) {
        let ring = cos(6.2831853 * edge / (0.45 * r + blur)) * exp(-edge / (0.9 * r));
        i = i + 0.10 * soft * ring;
    }
    return i;
}

@fragment
fn fs_main(v: VsOut) -> @location(0) vec4<f32> {
    // uv.y = 1 at the top of the viewport: µm y grows upwards.
    let p = u.view.xy + (v.uv * 2.0 - 1.0) * u.view.zw;
    let blur = u.params.x;
    // Köhler illumination: bright, slightly uneven background.
    let vign = 1.0 - 0.12 * dot(v.uv - 0.5, v.uv - 0.5);
    var i = 0.80 * vign;
    let n = i32(u.params.w);
    for (var k = 0; k < 16; k = k + 1) {
        if (k < n) {
            i = i + bead_intensity(p, u.beads[k], blur);
        }
    }
    // camera noise: new pattern every camera frame
    i = i + u.params.y * (hash(floor(v.pos.xy), u.params.z) - 0.5);
    i = clamp(i, 0.0, 1.0);
    var col = vec3<f32>(i * 0.97, i, i * 0.93);
    // trap marker: a thin ring (green; red while the emergency stop is latched)
    let dt = abs(length(p - u.trap.xy) - u.trap.z);
    let m = 1.0 - smoothstep(0.04, 0.12, dt);
    var mc = vec3<f32>(0.1, 0.85, 0.25);
    if (u.trap.w > 0.5) {
        mc = vec3<f32>(0.95, 0.1, 0.1);
    }
    col = mix(col, mc, 0.8 * m);
    return vec4<f32>(col, 1.0);
}
