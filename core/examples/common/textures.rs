//! Procedural texture sources for the blind-deblurring harness's `texture` tuning split:
//! repetitive structure (tiled walls, packed pebbles, grass-like strands), the kind of scene
//! the README's limits name as a failure case, drawn from generators instead of photos so that
//! the held-out split's real texture photos (brick, grass, gravel) stay untouched.

use super::rng::Rng;

/// Side of a generated source (px); the harness rescales and crops it like a photo.
const SIDE: usize = 640;

/// A grey source in `[0, 1]`, as the harness's `load` returns.
pub type Source = (usize, usize, Vec<f32>);

/// A running bond of rectangular tiles (row height 6–18 px, tiles 2–4 rows long, mortar 1–3 px
/// darker or lighter than the tiles), rotated by a random angle, each tile its own grey with a
/// faint grain.
pub fn tiles(seed: u64) -> Source {
    let mut rng = Rng::new(seed);
    let row = rng.range(6.0, 18.0);
    let len = row * rng.range(2.0, 4.0);
    let mortar = rng.range(1.0, 3.0);
    let mortar_grey = if rng.uniform() < 0.5 {
        rng.range(0.1, 0.25)
    } else {
        rng.range(0.75, 0.9)
    };
    let angle = rng.range(0.0, std::f64::consts::PI);
    let (c, s) = (angle.cos(), angle.sin());
    let grey = |i: i64, j: i64| 0.3 + 0.4 * hash01(seed, i, j);
    let mut data = Vec::with_capacity(SIDE * SIDE);
    for y in 0..SIDE {
        for x in 0..SIDE {
            let (fx, fy) = (x as f64, y as f64);
            let u = c * fx + s * fy;
            let v = -s * fx + c * fy;
            let r = (v / row).floor();
            let shift = if (r as i64).rem_euclid(2) == 1 {
                len / 2.0
            } else {
                0.0
            };
            let t = ((u + shift) / len).floor();
            let (du, dv) = ((u + shift) - t * len, v - r * row);
            let value = if du < mortar || dv < mortar {
                mortar_grey
            } else {
                grey(r as i64, t as i64)
            };
            data.push((value + 0.03 * rng.normal()).clamp(0.0, 1.0) as f32);
        }
    }
    (SIDE, SIDE, data)
}

/// Overlapping pebbles: ellipses of radius 4–14 px with random greys, each lit from one side
/// (a linear shading across it), dropped until the ground is covered several times.
pub fn pebbles(seed: u64) -> Source {
    let mut rng = Rng::new(seed);
    let mut img = vec![rng.range(0.2, 0.5); SIDE * SIDE];
    let light = rng.range(0.0, std::f64::consts::TAU);
    let (lx, ly) = (light.cos(), light.sin());
    let count = 2500;
    for _ in 0..count {
        let (cx, cy) = (
            rng.range(-10.0, SIDE as f64 + 10.0),
            rng.range(-10.0, SIDE as f64 + 10.0),
        );
        let a = rng.range(4.0, 14.0);
        let b = a * rng.range(0.5, 1.0);
        let th = rng.range(0.0, std::f64::consts::PI);
        let (c, s) = (th.cos(), th.sin());
        let g = rng.range(0.15, 0.85);
        let shade = rng.range(0.05, 0.2);
        let (x0, x1) = (
            (cx - a).floor().max(0.0) as usize,
            ((cx + a).ceil() as usize).min(SIDE - 1),
        );
        let (y0, y1) = (
            (cy - a).floor().max(0.0) as usize,
            ((cy + a).ceil() as usize).min(SIDE - 1),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
                let d = (u / a).powi(2) + (v / b).powi(2);
                if d <= 1.0 {
                    let lit = (dx * lx + dy * ly) / a;
                    img[y * SIDE + x] = (g + shade * lit).clamp(0.0, 1.0);
                }
            }
        }
    }
    let data = img
        .into_iter()
        .map(|v| (v + 0.02 * rng.normal()).clamp(0.0, 1.0) as f32)
        .collect();
    (SIDE, SIDE, data)
}

/// Grass-like strands: thin (1–2 px) strokes 10–40 px long, leaning within ±35° of one
/// direction, light on a dark ground, drawn until the ground is mostly hidden.
pub fn strands(seed: u64) -> Source {
    let mut rng = Rng::new(seed);
    let mut img = vec![rng.range(0.05, 0.25); SIDE * SIDE];
    let main = rng.range(0.0, std::f64::consts::PI);
    for _ in 0..9000 {
        let (x, y) = (rng.range(0.0, SIDE as f64), rng.range(0.0, SIDE as f64));
        let th = main + rng.range(-0.6, 0.6);
        let len = rng.range(10.0, 40.0);
        let width = rng.range(0.6, 1.2);
        let g = rng.range(0.35, 0.95);
        let steps = (len * 2.0) as usize;
        for k in 0..steps {
            let t = k as f64 / 2.0;
            let (px, py) = (x + t * th.cos(), y + t * th.sin());
            let r = width.ceil() as i64;
            for oy in -r..=r {
                for ox in -r..=r {
                    let (qx, qy) = (px.round() as i64 + ox, py.round() as i64 + oy);
                    if qx < 0 || qy < 0 || qx >= SIDE as i64 || qy >= SIDE as i64 {
                        continue;
                    }
                    let d = ((qx as f64 - px).powi(2) + (qy as f64 - py).powi(2)).sqrt();
                    if d <= width {
                        img[qy as usize * SIDE + qx as usize] = g;
                    }
                }
            }
        }
    }
    let data = img
        .into_iter()
        .map(|v| (v + 0.02 * rng.normal()).clamp(0.0, 1.0) as f32)
        .collect();
    (SIDE, SIDE, data)
}

/// A uniform value in `[0, 1)` from a seed and two integers (a tile's grey).
fn hash01(seed: u64, i: i64, j: i64) -> f64 {
    let mut h = seed
        ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
        ^ (j as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f);
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}
