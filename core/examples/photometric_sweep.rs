//! Why over 600 lines: about a hundred of them are the measured record of each split and of
//! each change tried against it, kept next to the generators that produced the numbers.
//!
//! Accuracy sweep of the online photometric calibration (issue 16): synthetic auto-exposure
//! videos over many camera responses (random monotone EMoR draws, gamma curves 1.0–2.6),
//! scenes, vignettes and exposure programs, scored like the shared `score_ref.json` (inverse
//! responses min-max normalised over levels 1..254, the exponential gauge `f → f^α` aligned
//! to the truth and applied to vignetting and exposures).
//!
//! Two disjoint sets, so that tuning on one does not flatter the other:
//!
//! * `tuning`: seeds 0.., AE-controller programs, the wave texture, polynomial vignettes;
//! * `eval`: seeds from 1000, other response draws, scripted sweep/step exposure programs
//!   mixed with other controller settings, the Voronoi-patch scene and a cos⁴ vignette (a law
//!   the polynomial model only approximates) on half the cases.
//! * `saturated`: seeds from 2000, a second tuning set for clipping: auto-exposure aiming high
//!   or a manual exposure drifting at random (slowly or fast, up to ±1.6 stops), a Mondrian
//!   scene and a Gaussian vignetting law on some cases; 26–61 % of the pixels clipped. Its
//!   program, scene and law are not those of `eval`, which stays held out.
//! * `scripted`: seeds from 3000, a third tuning set with `eval`'s scripted sweep/step
//!   programs (the ones behind its misses) on the wave or Mondrian scene and polynomial or
//!   Gaussian vignettes; `eval` stays held out by seed, response draw, scene and law.
//! * `lens`: seeds from 4000, a fourth tuning set for the vignetting model: the tuning
//!   programs and scenes under mechanical vignetting (a plateau, then a smoothstep shoulder)
//!   or a strong Gaussian law, neither of them `eval`'s cos⁴.
//! * `scenes`: seeds from 5000, a fifth tuning set for scene dependence: a dead-leaves scene
//!   (occluding discs, used by no other set) under `eval`'s program mix and polynomial or
//!   Gaussian vignetting.
//! * `eval2`: seeds from 6000, `eval`'s generators (programs, Voronoi patches, cos⁴) with fresh
//!   seeds and no fixed responses: a second held-out set, added 2026-12-04 because `eval` had
//!   by then been run after many candidate changes; it confirms or refutes a choice once.
//! * `eval3`: seeds from 7000, the same generators again: a third held-out set, added
//!   2026-12-05 and run once on the fit as shipped: 10 of 12 within all four targets
//!   (medians 0.0012 / 0.0028 / 0.40 %, time median 3.7 s, worst 5.6 s); misses `eval3#3`
//!   (EMoR, f(0.5) = 0.78, sweep program: the gauge came out at f(0.5) = 0.85, α 0.73;
//!   response 0.0064, exposures 2.07 %) and `eval3#7` (steps program, tracks split at frame
//!   126: refused, the parts named). Not yet used for any choice. `eval3#3` with the gauge
//!   given (`SWEEP_PARAMS='{"gamma_gauge": 0.78}' … eval3 12 200 320 240 3`) meets all
//!   targets (0.0006 / 0.0017 / 0.73 %), with the same robust RMS (1.97) as at the chosen
//!   0.85: the miss is the gauge choice on a flat profile, as for the tuning cases above.
//! * `eval4`: seeds from 8000, the same generators again: a fourth held-out set, added
//!   2026-12-05 (later) and run once on the fit as shipped, after a gauge prior tried for
//!   `eval3#3` had been dropped on the tuning splits (`online/gauge.rs`): 10 of 12 within all
//!   four targets (medians 0.0012 / 0.0018 / 0.54 %, time median 4.1 s, worst 5.5 s); misses
//!   `eval4#1` (EMoR, f(0.5) = 0.86, steps, cos⁴ vignette, 35 % clipped: gauge 0.864, vignette
//!   0.0201 with the polynomial kept by `auto`) and `eval4#3` (EMoR, f(0.5) = 0.73, sweep
//!   program: exposure error 2.33 %). Not yet used for any choice. Looked at after (settings
//!   by `SWEEP_PARAMS`, diagnosis only): `eval4#1`'s vignette stays off with the spline
//!   (0.0155), at the true gauge (0.0152), with Huber 6 levels (0.0211) or the centre fitted
//!   (0.0201), so neither the model, the gauge nor the centre is what misses there.
//! * `eval5`: seeds from 9000, the same generators again: a fifth held-out set, fixed
//!   2026-12-05 (evening) before the second tracking pass (`online/response_match.rs`) was
//!   chosen on the tuning splits, to confirm it once.
//! * `eval6`: seeds from 10 000, the same generators again: a sixth held-out set, fixed
//!   2026-12-06 before the gauge hysteresis of the second pass was tried, to confirm it once.
//! * `eval7`: seeds from 11 000, the same generators again: a seventh held-out set, fixed
//!   2026-12-06 (session start, before any change) to confirm a cheaper second pass once.
//! * `eval8`: seeds from 12 000, the same generators again, fixed 2026-12-06 after `eval7`
//!   had been looked at (its `eval7#4` led to refusing tracks that break in the second pass).
//! * `eval9`: seeds from 13 000, the same generators again, fixed 2026-12-06 (next session's
//!   start, before any change) to confirm that session's choices once.
//! * `soft`: seeds from 14 000, the tuning generators seen through a soft lens (a Gaussian blur
//!   of σ 0.6–2 px on the irradiance, before the response: `AeVideo::optics_blur`); every
//!   other split is point-sampled and sharp at the pixel scale, which real cameras are not.
//! * `soft-eval`: seeds from 15 000, `eval`'s generators through the same soft lens, held out.
//! * `soft-eval2`: seeds from 16 000, the same again: fixed 2026-12-06 (fourth session's start,
//!   before any choice); used once, to confirm that session's compression levels.
//! * `fisheye`: seeds from 17 000, a fisheye's image circle (cos⁴ inside a logistic border,
//!   centred, cutting the frame's top and bottom or only its corners); tuned on.
//! * `fisheye-eval`, `fisheye-eval2`: seeds from 18 000 and 19 000, held out: another border
//!   law (a raised cosine reaching black, `(1 − a r²)²` inside), off-centre by up to ±6 px per
//!   axis, `eval`'s programs and scenes. Both have been seen (the first while the circle was
//!   developed, the second to measure it and then to choose the centre rule).
//! * `fisheye-eval3`: seeds from 20 000, `fisheye-eval`'s generators; `fisheye2`: seeds from
//!   21 000, `fisheye`'s (centred). Both fixed 2026-12-06 before the centre choice of
//!   `online/vig_stage.rs` was measured on them, each run once as shipped and once with the
//!   image centre forced.
//! * `fisheye-eval4`: seeds from 22 000, `fisheye-eval`'s generators, fixed 2026-12-06 before
//!   the 18 spline knots inside the circle (`vig_model::CIRCLE_KNOTS`, chosen on `fisheye` and
//!   `fisheye-eval`) were measured on it, run once with 18 and once with the 12 before.
//! * `fisheye-erf`: seeds from 23 000, a third image-circle law used by no other split and
//!   never tuned on: an equidistant fisheye's `cos³ θ` inside the border of a defocused field
//!   stop (an erfc edge, `VignetteForm::FisheyeErf`), off-centre by up to ±8 px per axis,
//!   `eval`'s programs and scenes. `fisheye-eval5` (seeds from 24 000, `fisheye-eval`'s
//!   generators) and `fisheye3` (seeds from 25 000, `fisheye`'s): fresh seeds of the older
//!   families. All three fixed 2026-12-07 before the border-free gauge and the equal-area
//!   knots (`online/circle.rs`, `online/vig_model.rs`) were measured on them.
//! * `fisheye-erf2`, `fisheye-erf3` (seeds from 26 000 and 28 000, `fisheye-erf`'s generators)
//!   and `fisheye-eval6` (27 000, `fisheye-eval`'s): fixed 2026-12-07 before the centre refit
//!   of `online/vig_stage.rs` was measured on them, each run once with it and once without.
//! * `fisheye-erf4` (29 000, `fisheye-erf`'s) and `fisheye-eval7` (30 000, `fisheye-eval`'s):
//!   fixed 2026-12-07 (the next session) after every choice of the refit, to confirm it once.
//!   A split's printout gives each fisheye case's vignetting centre and its distance from the
//!   true one.
//! * `fisheye-eval8` (31 000, `fisheye-eval`'s) and `fisheye-erf5` (32 000, `fisheye-erf`'s):
//!   fixed 2026-12-07 (third session) after the image circle's outside share was lowered
//!   (`online/circle.rs`, `MIN_OUTSIDE_SHARE`, chosen on `fisheye-eval7#2`), to confirm it once.
//! * `fisheye-eval9` (33 000, `fisheye-eval`'s) and `fisheye-erf6` (34 000, `fisheye-erf`'s):
//!   fixed 2026-12-07 (third session) to check a border-aware gradient weight of the samples
//!   (the scene's part `∇I − I·∇ln M` beyond 0.7 of the circle's radius, `M` the mean levels;
//!   found on `fisheye-eval8` and `fisheye-erf5`), run once with it and once without: 8 of 12
//!   either way on both, vignette medians 0.0066 against 0.0079 and 0.0045 against 0.0048, but
//!   `fisheye-eval9#4` flipped from 0.0007 / 0.0066 / 0.52 % to 0.050 / 0.048 / 4.3 % (and the
//!   tuning split's `fisheye-eval2#1` likewise). Not kept; see the README's limits.
//! * `fisheye-eval10` (35 000, `fisheye-eval`'s) and `fisheye-erf7` (36 000, `fisheye-erf`'s):
//!   fixed 2026-12-07 (fourth session) before the border stage (`online/border.rs`) was
//!   chosen on the tuning splits, run once with it and once without: 6 and 10 of 12 either
//!   way (vignette better on 8 of 11 and 7 of 12, worse on none and on 2 by 0.0001).
//! * `fisheye-eval11` (37 000, `fisheye-eval`'s) and `fisheye-erf8` (38 000, `fisheye-erf`'s):
//!   fixed 2026-12-07 (fourth session, later) before the vignetting centre's refit with the
//!   border stage's weights was tried on the tuning splits (it mended `fisheye-erf5#6`, 0.0124
//!   → 0.0052, but left `fisheye-eval` and `fisheye-eval2` at 10 of 12 with vignette medians
//!   0.0049 → 0.0051 and 0.0058 → 0.0063); not kept, so both were still unseen until the
//!   rule below was confirmed on them.
//! * `fisheye-wide` (39 000): a tuning split added 2026-12-07 (fifth session) for the case
//!   `fisheye-eval10#6` showed: `fisheye`'s logistic circle at radius 0.9–1.05 of the
//!   half-diagonal (the border at or past the corners) and off-centre by up to ±6 px per
//!   axis. Sequences within the three accuracy targets (time aside), vignette and exposure
//!   medians: as shipped 1 of 12 (0.0209, 2.67 %); `vignette_model: spline` 0 (0.0218,
//!   2.65 %); `vignette_center: auto` 6 (0.0094, 0.40 %); both 5 (0.0108, 0.40 %). The
//!   decentred border is what misses, and the circle detector finds no circle there (its
//!   printout is the truth's circle), so `fixed` stays at the image centre. Tried: `fixed`
//!   acting as `auto` whenever a circle *is* found. `fisheye-wide` unchanged (1 of 12, no
//!   circle found), confirmed once on `fisheye-eval11` (vignette the same to 0.0001 on every
//!   case) and `fisheye-erf8` (one case worse, `#1` 0.0085 → 0.0187, the rest the same):
//!   not kept. Both are now seen. A rule for the no-circle case (a decentred steep fall-off
//!   without a detected border) is what is left; the standard splits' lenses, where `auto`
//!   wanders by 4–49 px, must stay at the image centre, so it needs a sign that tells a
//!   fisheye's dark corners from a strong polynomial fall-off.
//!
//! Fisheye gauge and knots (2026-12-07). `SWEEP_RADIAL=1` splits the vignette error by the
//! true level and prints the spline's values: on `fisheye-eval` and `fisheye-eval2` the misses
//! were a gauge far off (α 0.51–2.64), a response from the polynomial fit, and an interior
//! uniformly low under a spline whose first knot sat up to 10 % below `V(0) = 1`. Chosen on
//! `fisheye 8`, `fisheye-eval 12` and `fisheye-eval2 12` (sequences within all three accuracy
//! targets, 32 in all): as shipped before 8; gauge inside 0.7 of the radius, the spline's
//! response and equal-area knots 20 (0.8: 20, 0.9: 18, the whole circle: 15; without the
//! spline's response 8 of 21 run). Held out, each run once with the change and once without:
//! `fisheye-eval5 12` 9 against 2, `fisheye-erf 12` 5 against 4, `fisheye3 8` 4 against 3
//! (medians in the README's limits).
//!
//! Soft optics (2026-12-06, third session; nothing in the fit changed). Run once each on the
//! fit as shipped, 200 frames at 320×240, 2 cores (this machine fits the shared
//! `ae_seq_seed0` in 9.5 s where the previous one took 5.4 s, so the times are not comparable
//! with the records above): `soft` 11 of 12 within the three accuracy targets (medians
//! 0.0010 / 0.0028 / 0.39 %; the miss `soft#7` is a camera with f(0.5) = 0.96, the concave
//! family below: 0.0124 / 0.0091 / 3.37 %), 8.1 s median, 9.6 s worst; `soft-eval` 11 of 12
//! (medians 0.0011 / 0.0022 / 0.43 %; the miss `soft-eval#0`, f(0.5) = 0.77 under the sweep
//! program, the gauge off: α 1.70, 0.0104 / 0.0146 / 1.74 %), 9.2 s median, 10.9 s worst. Stronger blur
//! and faster motion on `tuning#0` and `#2` (`SWEEP_BLUR`, `SWEEP_SPEED`): σ = 4 px still
//! meets the targets but loses accuracy (`#0` 0.0019 / 0.0082 / 1.46 % against 0.0002 /
//! 0.0010 / 0.32 % sharp, `#2` 0.0017 / 0.0007 / 0.87 % against 0.0010 / 0.0005 / 0.20 %);
//! `#0` with 2× and 4× the motion (4–8 px per frame) 0.0002–0.0004 / 0.0007–0.0009 /
//! 0.36–0.61 %. Rendered at 1280×960 (more of the scene, same pixel scale),
//! `tuning 4 200 1280 960`: the same passes and misses as at 320×240 (`#3`'s vignette 0.0118),
//! 14–19 s per sequence. A frame upscaled 4× after the response (bicubic, so edges are
//! mixtures of recorded values, which no lens produces) lost most of its tracks (mean track
//! length 3 against 20) and its exposures were 2.7 % off.
//!
//! Compression (same session): `ae_seq_seed0`'s frames encoded with x264 (High, yuv420p,
//! 20 fps) and fitted through `SWEEP_CLIP` (`shared`), response / vignette / exposure: CRF 8
//! (the shared clip, 2.0 bits per pixel) 0.0009 / 0.0006 / 0.31 %, CRF 18 (0.26) 0.0006 /
//! 0.0010 / 0.72 %, CRF 23 (0.09) 0.0016 / 0.0033 / 2.04 %, CRF 28 (0.05) 0.0024 / 0.0070 /
//! 3.98 %; the PNG frames 0.0002 / 0.0005 / 0.12 %. The exposure error at CRF 28 drifts with
//! the exposure (about −5 % in the bright first frames, +7 % at the dark end, after the best
//! common scale; `SWEEP_FRAMES=1 SWEEP_ALL=1`): the predicted frames' quantised residuals
//! understate small brightness changes.
//!
//! Compression over the sweep's own cases (2026-12-06, fourth session; nothing in the fit
//! changed). `SWEEP_CRF=N` encodes every rendered case with x264 (High, yuv420p, 20 fps,
//! rate factor N, `SWEEP_X264` extra options) through `ffmpeg` and fits the decoded clip;
//! `SWEEP_CRF=mjpeg:Q` writes Motion-JPEG at ffmpeg quality Q. Cases within the three accuracy
//! targets of 12 (medians response / vignette / exposure): `tuning` as frames 10 (0.0014 /
//! 0.0011 / 0.30 %), CRF 14 11 (0.0022 / 0.0017 / 0.71 %), 18 10 (0.0020 / 0.0023 / 1.02 %), 23
//! 5 (0.0054 / 0.0063 / 2.02 %), 28 0 (0.0058 / 0.0146 / 2.67 %); `soft` as frames 11 (0.39 %),
//! CRF 14 11 (0.59 %), 18 11 (0.91 %), 23 1.46 % and 28 2.73 % at the median. By the clip's bits
//! per pixel over both splits (96 clips): ≥ 0.5 19 of 22 (exposure 0.67 %), 0.15–0.5 24 of 27
//! (0.95 %), below 0.15 12 of 47 (2.4 %) — the levels of `online/compression.rs`. Diagnosis on
//! `tuning` at CRF 23 (5 of 12): without B-frames (`SWEEP_X264='-bf 0'`) 6 (1.39 %); every frame
//! intra (`-g 1`, 0.26–0.33 bits per pixel) 3 (2.31 %): independent quantisation in every frame
//! costs more than prediction does; gradient weight halving at 0.01 instead of 0.03 6 (2.09 %);
//! samples at ±4 px instead of ±2 7 (1.61 %) but as frames 11 with worse medians (0.0017 /
//! 0.0019 / 0.40 %), so the sampling stays. Motion-JPEG: quality 2 (1.1–1.9 bits per pixel) 9
//! (0.44 %), 5 (0.6–0.8) 9 (0.46 %), 10 (0.4–0.6) 4 (2.61 %); read as limited range (the
//! service's default before `luma_range: auto`) `tuning#0` at quality 4 was 11.8 % off, 0.52 %
//! in full range. Held out, run once after the levels were set: `soft-eval2` as frames 12 of
//! 12 (0.0009 / 0.0020 / 0.42 %), CRF 18 9 (0.0011 / 0.0051 / 1.02 %), CRF 23 6 (0.0028 /
//! 0.0112 / 1.88 %); by level, moderate (0.15–0.29 bits per pixel) 9 of 11 (0.97 %), heavy
//! (0.05–0.14) 6 of 13 (1.82 %).
//!
//! ```text
//! CARGO_TARGET_DIR=... cargo run -p caliper-core --release --example photometric_sweep -- \
//!     [tuning|saturated|scripted|lens|scenes|soft|eval|eval2|…|eval9|soft-eval|fisheye…|shared] [cases] [frames] [width] [height]
//! ```
//!
//! The second tracking pass (2026-12-05, evening; `online/response_match.rs`). `eval4`'s two
//! misses came from where the tracker puts the samples, and tracking on frames linearised by
//! the response fixed both (`online/diag_tests.rs`, `DIAG_LIN`). Built as a second pass after
//! a first fit and judged on the tuning splits only (cases within the accuracy targets,
//! `tuning` / `saturated` / `lens` / `scenes` / `scripted`):
//!
//! | second pass | result | of 60 |
//! |---|---|---|
//! | none (one pass, the default) | 11 / 12 / 11 / 8 / 12 | 54 |
//! | tracked on frames linearised by the first fit's response | 9 / (3 of 4 run) / stopped | — |
//! | tracked again, matches re-aligned through the response, gauge chosen again (`tracking_passes: 2`) | 10 / 12 / 10 / 11 / 12 | 55 |
//! | the first pass's tracks re-aligned through the response (no new tracking), gauge again | 10 / 12 / 10 / 9 / 11 | 52 |
//! | re-aligned, started from the first fit with its gauge kept | 10 / (8 of 8 run) / 11 / 8 / — | — |
//! | tracked again, started from the first fit with its gauge kept | 11 / — / 11 / 9 / — | — |
//!
//! On linearised frames the match weighs the noise of the steep end of `f⁻¹` as much as the
//! rest (`tuning#1` 0.0034 → 0.0116, `tuning#4` 0.0008 → 0.0058). Re-aligning through the
//! response keeps the residual in recorded intensities; on the scenes of occluding discs it
//! moves the gauge choice to the right basin (8 → 11 of 12), but where the gauge profile is
//! flat the new samples tip it elsewhere (`lens#3`, `lens#9`: gauge 0.54 → 0.31 and 0.61 →
//! 0.48, response 0.001 → 0.006), and keeping the first gauge keeps the scenes' wrong ones. A
//! cold start at the first pass's gauge ended in another basin (`tuning#1` 0.050). So the
//! second pass is an option, not the default: 55 against 54 of 60 is not a difference, and it
//! doubles the time.
//!
//! The first pass's gauge as a candidate of the second pass's profile (2026-12-06,
//! `online/gauge.rs`): the new profile's grid sometimes misses the basin the first pass had
//! found (`lens#3`: chosen 0.31, while the first pass's 0.54 refitted on the new samples costs
//! 8.6 % less). Kept when it costs no more: tuning splits 10 / 12 / 12 / 11 / 12 = **57 of
//! 60** (two passes before: 55, one pass: 54), median response 0.0012 → 0.0010; a 0.2 % margin
//! in favour of the first gauge also gave 57 (fixes `tuning#1`, loses `lens#0`) and was not
//! taken. Then `eval6` (seeds from 10 000, fixed before the change, run once per setting with
//! the same binary, 2 cores, nothing else running): two passes **12 of 12** within the three
//! accuracy targets (medians 0.0008 / 0.0024 / 0.42 %, worst 0.0031 / 0.0067 / 1.67 %), 8.5 s
//! median and 10.6 s worst, so 11 of 12 also within the 10 s budget; one pass 11 of 12
//! (0.0014 / 0.0035 / 0.56 %; the miss an exposure error of 3.2 % under the sweep program and
//! a cos⁴ vignette), 4.3 s median, 5.2 s worst. The tracker's samples were made cheaper the
//! same day (one interleaved array per level, no `floorf`, the next pyramid built while the
//! tracks are matched) with identical results: `eval6#2` 11.8 → 10.4 s with two passes.
//!
//! `broken_tracks: per_part` (2026-12-06, `online/linked.rs`) on the three sequences refused
//! for broken tracks so far (`SWEEP_PARAMS='{"broken_tracks":"per_part"}' … <split> 12 200 320
//! 240 <case>`; exposures scored with one scale per part): `eval#1` (a linear camera, steps)
//! 0.0019 / 0.0041 / 0.95 %, `eval2#7` (f(0.5) = 0.89, 66 % clipped) 0.0028 / 0.0060 / 0.92 %,
//! `eval5#10` (f(0.5) = 0.78) 0.0017 / 0.0030 / 0.49 %: all within the targets. These
//! sequences had been seen (as refusals); nothing was tuned on them, the option has no
//! constant.
//!
//! Two passes as the default (2026-12-06, later). The fit was made faster with identical
//! results (the gauge grid and the local brackets fitted in parallel, only the upper triangle
//! of the Schur complement, `exp` once per frame and point, `f` alone in the cost): `lens#7`
//! 11.3 → 10.6 s, `tuning#3` 12.1 → 8.4 s with two passes. Then the first of two passes was
//! cut to a first look that stops at the gauge profile (`online::first_look`: the second pass
//! takes only its response and gauge). Tuning splits, two passes, 2 cores, quiet machine:
//!
//! | | tuning | saturated | lens | scenes | scripted | of 60 | split medians / worst time |
//! |---|---|---|---|---|---|---|---|
//! | faster fit, identical results | 10 | 12 | 12 | 11 | 12 | 57 | 6.2–9.0 / 11.3 s |
//! | first look | 10 | 12 | 12 | 12 | 12 | **58** | 5.8–7.5 / 8.9 s |
//!
//! (medians of response / vignette / exposure per split 0.0013 / 0.0011 / 0.30 %,
//! 0.0009 / 0.0010 / 0.26 %, 0.0008 / 0.0043 / 0.23 %, 0.0007 / 0.0023 / 0.50 %,
//! 0.0007 / 0.0009 / 0.22 %.) Held out, `eval7` (fixed at the start of that session) run once
//! per setting with the same binary: two passes 11 / 12 within the accuracy targets (medians
//! 0.0007 / 0.0010 / 0.27 %, 6.35 s median, 7.39 s worst), one pass 11 / 12 (0.0014 / 0.0015
//! / 0.51 %, 3.40 s, 4.25 s). Its miss, `eval7#4` (steps, 35 % clipped), was the same in both:
//! the second pass's tracks broke into two parts, the pass fell back to the first, whose link
//! across the break left the exposures 8.4 % off (per part with two passes: 0.0014 / 0.0034 /
//! 1.13 %). So a break found by the second pass is now refused like the first pass's. No
//! tuning sequence changed with that (none fell back), and `eval8` (fixed after `eval7` was
//! seen, run once per setting, a build running beside it): two passes 11 / 12 (0.0009 /
//! 0.0012 / 0.34 %, 7.6 s median, 9.1 s worst), one pass 11 / 12 (0.0012 / 0.0023 / 0.54 %,
//! 4.3 s, 4.6 s); the miss `eval8#10` is a camera with f(0.5) = 0.96 (two passes 0.0112 /
//! 0.0095 / 3.51 %, one 0.0102 / 0.0113 / 2.46 %), the family of `tuning#1` and `tuning#6`.
//! Raising the local steps' cap from 0.945 to 0.985 changed neither tuning case (their
//! choices, 0.87 and 0.88, are not at the cap) and was not kept.
//!
//! The strongly concave cameras (2026-12-06, second session; `online/diag_tests.rs`,
//! `diag_tuning6`, and `measured levels` in this example's output). `tuning#6` (f(0.5) =
//! 0.955) fails at every gauge the fit may choose, and not from the tracker alone: with
//! ideal, noise-free samples at every pixel the fit is exact at the true gauge, but at 0.94
//! (the largest `gamma_gauge` accepts) it leaves the response 0.059 off at a residual of 0.34
//! levels, so for this curve EMoR-4 follows the truth's exponential family only close to the
//! true gauge. The tracks' samples stop at level 213 (the 99.9 % quantile of the measured
//! ones), with 75 % of the camera's normalised irradiance range above it (`tuning#1`: 227,
//! 45 %): the auto-exposure holds the picture at a mean of 0.32, and the bright frames are the
//! first two of its transient (exposure 1.00, 0.58, 0.37, …), and only 27 of frame 0's samples
//! reach the fit. Dropping the first one or three frames does not help (`#6`
//! 0.051 / 0.11). Tried, none kept (cases `#6` / `#1`, response / vignette / exposure):
//! * `max_features: 600` in both passes: 0.0075 / 0.021 / 2.12 % and 0.0041 / 0.0029 /
//!   0.78 % (gauges 0.945 and 0.910); over the tuning splits `tuning` 11 / 12 but `lens` 10 /
//!   12 (`lens#3` response 0.0082, `lens#4` vignette 0.040), 9–13 s per sequence;
//! * 600 features in the second pass only, when the first look's f(0.5) ≥ 0.85: 0.040 /
//!   0.070 / 25.6 % and 0.0100 / 0.0068 / 2.79 % (the second profile chose 0.905 and 0.865);
//! * 450 features in both passes: `#6` 0.011 / 0.030 / 5.4 %; nine samples per track: 0.055
//!   and 0.0145; `high_cut` 0.992 or 0.996: `#6` unchanged (nothing measured up there);
//! * the tracker's corner threshold (1e-4 of the structure tensor's smaller eigenvalue) at 3e-5
//!   or 1e-5: identical results (every cell's best corner is above it).
//!
//! `eval9` (fixed at that session's start, run once on the fit as shipped, none of the variants
//! above in it): 11 of 12 within the three accuracy targets, medians 0.0008 / 0.0021 /
//! 0.38 %, 5.4 s median, 6.4 s worst; the miss `eval9#0` is a camera with f(0.5) = 0.93 under
//! the sweep program, 33 % clipped: 0.0091 / 0.0142 / 3.54 %.
//!
//! The exposure error is scored like `score_ref.json`'s `ratio_rmse_pct_gauge_aligned`: RMS
//! relative error after the gauge exponent and the best common scale (exposures are defined up
//! to one factor); the error relative to frame 0 is printed beside it.
//!
//! The `lens` split's one miss, `lens#0` (exposure error 2.36 % on a 25× exposure range, the
//! error growing with the exposure), does not follow the settings (`SWEEP_PARAMS`, 2026-12-04):
//! polynomial vignetting 2.30 %, Huber 6 levels 2.88 %, `low_cut` 0.03 2.19 %, 12 000 points
//! 2.40 %, 9 samples per track 2.38 % (response 0.0064 → 0.0103); `max_iterations` 100 changes
//! no `lens` case (the fit has converged when it stops at 40).
//!
//! The `scenes` split (2026-12-04): 8 of 12 within all four targets before any change
//! (misses `scenes#0` response 0.0086 / exposure 2.75 %, `#1` 0.0119 / 3.01 %, `#3` vignette
//! 0.0120, `#10` response 0.0121; 15–48 % clipped), so the accuracy depends on the scene.
//! Two local minima of the gauge profile polished instead of one (`online/gauge.rs`): 9 of 12,
//! the other tuning splits unchanged (`tuning` 11, `scripted` 12, `saturated` 12, `lens` 11);
//! `eval`, run once with it and once without: 8 of 12 either way, the same four misses, one
//! exposure error worse (2.38 → 3.34 %). Not kept.
//! Also tried and not kept (with one polished minimum unless said):
//! * samples whose four source pixels spread more than 0.05 of full scale left out
//!   (`online/diag_tests.rs`, `diag_discs`): `scenes` 8 → 11, but `tuning` 11 → 10 (`tuning#1`,
//!   the strongly concave response: 0.0132 / 0.0191 / 3.3 %) and `lens` 11 → 9 (`auto` kept
//!   the polynomial on two mechanical lenses: vignette 0.041); the old `lens#0` miss passed
//!   (exposure 2.36 → 0.38 %). With the two polished minima: `scenes` 12, `tuning` 10, `lens`
//!   9 — the same 31 of 36 as the minima alone;
//! * those samples only down-weighted (× 10⁻³) in the gauge profile: `scenes` 9, `tuning` 4,
//!   `lens` 4;
//! * the edge weight halving at a gradient of 0.015 instead of 0.03: `scenes` 8.
//!
//! Tried 2026-12-04 (later), cases within all four targets out of 12, in the order
//! `scenes` / `tuning` / `lens` / `saturated` / `scripted` (tuning splits; as shipped
//! 8 / 11 / 11 / 12 / 12 = 54 of 60), then held out; none kept:
//! * the gauge profile relaxed to its lower envelope (each grid value refitted from a cheaper
//!   neighbour's converged state, forward then backward, the cheaper fit kept; `gauge.rs`):
//!   9 / 11 / 11 / 12 / 12 (`scenes#1` 0.0119 / 0.0080 / 3.0 % → 0.0007 / 0.0024 / 0.45 %),
//!   +1.2 s median per sequence; `eval` 8 of 12 either way, `eval#10` 0.0017 / 2.12 % →
//!   0.0053 / 2.99 %, `eval#1` exposure 2.38 → 2.81 %;
//! * with it, samples interpolated in the mean EMoR response's irradiance domain (the bilinear
//!   mix of `g₀` of the four pixels mapped back, against the `f(a)`/`f(b)` mixing at edges):
//!   `scenes` 9 (the same misses), `tuning` 11;
//! * with it, samples whose four source pixels spread more than 0.15 of full scale left out
//!   (2–40 % of the samples; on dead leaves a fifth of them spread over 0.2–0.36):
//!   11 / 10 / 11 / 12 / 11 = 55 of 60 (`tuning#1`, f(0.5) = 0.97, so fragile that dropping
//!   2 % of its samples moves its response error 0.0035 → 0.0087; `lens#3`'s `auto` kept the
//!   polynomial; `scripted#1` response 0.0064). `eval`: 10 of 12 (`eval#6` vignette 0.0118 →
//!   0.0011, `eval#10` exposure 2.12 → 1.56 %, but `eval#1`, the linear camera, lost a third
//!   of its samples and went 2.38 → 6.91 %). Chosen before `eval`, tied on tuning, better on
//!   `eval`: so `eval2` decided, run once for it and once as shipped: **9 of 12 either way**
//!   (the same misses; `eval2#0` vignette 0.0121 → 0.0207). Not kept;
//! * the spread relative to the mean of the four pixels, over 0.3 (so that a linear camera's
//!   bright texture is not dropped): 11 / 10 / 10 / 12 / – (`lens#0` exposure 3.83 %,
//!   `lens#4`'s `auto` kept the polynomial), 10 without the relaxed profile on `scenes`.
//!
//! `eval2` as shipped (run first with the code before this change, then with the parts
//! check): 9 of 12 within all four targets, medians 0.0012 / 0.0026 / 0.39 %; misses
//! `eval2#0` (vignette 0.0121), `eval2#4` (f(0.5) = 0.91: 0.0098 / 0.0147 / 2.1 %) and
//! `eval2#7`, whose tracks broke completely at frame 144 (66 % of the pixels clipped under
//! one-stop steps): its exposures after the break came out 12× off (error 97 %) with the
//! response and vignetting right. `photometric_online` now refuses such a video and names the
//! parts (`online/linked.rs`), so that case is an error instead of wrong exposures. The same
//! check refuses `eval#1` (tracks broken at frame 35; its exposures had come out 2.38 % off,
//! a miss either way); no case of the tuning splits or any other held-out case is refused,
//! and the numbers of the others are unchanged.
//!
//! `SWEEP_PARAMS='{"gamma_gauge": 0.5}'` (any `OnlineParams` JSON) runs the old fixed gauge
//! `f(0.5) = 0.5` for comparison. `SWEEP_FRAMES=1` prints the first frames' exposure errors
//! against the best common scale, each after `@` the frame's true exposure (`SWEEP_ALL=1`: also
//! every 10th frame; an error that follows the frame index and not the exposure is a drift along
//! the track chain); `SWEEP_DEBUG=1` prints each case's camera and video settings and the true
//! vignetting centre (to rebuild it in a diagnostic); `SWEEP_DUMP=DIR` writes
//! each case's first frame as a PNG. `shared` runs the
//! shared `ae_seq_seed0` (from `CALIPER_PHOTO_DATA`, default `../shared/data/photometric`)
//! instead; with `SWEEP_CLIP=clip.mp4` (and `--features video`) it fits the frames of an
//! H.264 clip of it (compression).

use std::path::{Path, PathBuf};
use std::time::Instant;

use caliper_core::io::ImageLimits;
use caliper_core::photometric::dso::read_vignette_png;
use caliper_core::photometric::metrics::{
    aligned_maps, exposure_error_common_pct, exposure_error_parts_pct, exposure_error_pct,
    gamma_align, vignette_rmse,
};
use caliper_core::photometric::synth::{
    AeVideo, ExposureProgram, Rng, SceneForm, SynthCamera, VignetteForm, clipped_fraction,
    render_ae_video,
};
use caliper_core::photometric::{
    InverseResponse, OnlineParams, PhotoImage, ResponseModel, photometric_online,
};

/// One scored run.
struct Row {
    name: String,
    resp: f64,
    vig: f64,
    /// Exposure error with the best common scale, % (the shared score's).
    exp: f64,
    /// Exposure error relative to frame 0, %.
    exp0: f64,
    secs: f64,
}

/// A monotone EMoR draw: `c_k ~ N(0, σ_k)` with σ shrinking like the EMoR eigenvalues,
/// rejected until the curve is strictly increasing.
fn emor_draw(rng: &mut Rng) -> ResponseModel {
    const SIGMA: [f64; 4] = [3.0, 1.2, 0.6, 0.3];
    loop {
        let mut c = [0.0; 4];
        for (k, x) in c.iter_mut().enumerate() {
            *x = SIGMA[k] * rng.normal();
        }
        let m = ResponseModel::Emor { c };
        if m.is_monotone() {
            return m;
        }
    }
}

/// `eval`'s exposure programs: a scripted sinusoidal sweep, held random steps or (every third
/// case) the given auto-exposure controller.
fn eval_program_mix(i: usize, rng: &mut Rng, auto: ExposureProgram) -> ExposureProgram {
    match i % 3 {
        0 => ExposureProgram::Sweep {
            stops: 0.5 + 1.0 * rng.uniform(),
            period: 40.0 + 80.0 * rng.uniform(),
            flicker: 0.03,
        },
        1 => ExposureProgram::Steps {
            stops: 0.5 + 1.0 * rng.uniform(),
            hold: 5 + (rng.uniform() * 20.0) as usize,
        },
        _ => auto,
    }
}

fn case(set: &str, i: usize, width: usize, height: usize) -> (String, SynthCamera, AeVideo) {
    // `eval2` … `eval5`: `eval`'s generators with fresh seeds (see the module notes).
    let eval = matches!(
        set,
        "eval"
            | "eval2"
            | "eval3"
            | "eval4"
            | "eval5"
            | "eval6"
            | "eval7"
            | "eval8"
            | "eval9"
            | "soft-eval"
            | "soft-eval2"
    );
    // `soft`, `soft-eval`: a lens blur on the irradiance (see `AeVideo::optics_blur`).
    let soft = matches!(set, "soft" | "soft-eval" | "soft-eval2");
    let saturated = set == "saturated";
    let scripted = set == "scripted";
    let lens = set == "lens";
    let scenes = set == "scenes";
    let fisheye = matches!(set, "fisheye" | "fisheye2" | "fisheye3");
    let fisheye_wide = set == "fisheye-wide";
    // A split's generator family is its name's prefix; its seeds come from the table below.
    let fisheye_eval = set.starts_with("fisheye-eval");
    let fisheye_erf = set.starts_with("fisheye-erf");
    let (seed, offset) = match set {
        "eval" => (1000 + i as u64, 17),
        "saturated" => (2000 + i as u64, 29),
        "scripted" => (3000 + i as u64, 41),
        "lens" => (4000 + i as u64, 53),
        "scenes" => (5000 + i as u64, 67),
        "eval2" => (6000 + i as u64, 79),
        "eval3" => (7000 + i as u64, 97),
        "eval4" => (8000 + i as u64, 101),
        "eval5" => (9000 + i as u64, 103),
        "eval6" => (10_000 + i as u64, 107),
        "eval7" => (11_000 + i as u64, 109),
        "eval8" => (12_000 + i as u64, 113),
        "eval9" => (13_000 + i as u64, 127),
        "soft" => (14_000 + i as u64, 131),
        "soft-eval" => (15_000 + i as u64, 137),
        "soft-eval2" => (16_000 + i as u64, 139),
        "fisheye" => (17_000 + i as u64, 149),
        "fisheye-eval" => (18_000 + i as u64, 151),
        "fisheye-eval2" => (19_000 + i as u64, 157),
        "fisheye-eval3" => (20_000 + i as u64, 163),
        "fisheye2" => (21_000 + i as u64, 167),
        "fisheye-eval4" => (22_000 + i as u64, 173),
        "fisheye-erf" => (23_000 + i as u64, 179),
        "fisheye-eval5" => (24_000 + i as u64, 181),
        "fisheye3" => (25_000 + i as u64, 191),
        "fisheye-erf2" => (26_000 + i as u64, 193),
        "fisheye-eval6" => (27_000 + i as u64, 197),
        "fisheye-erf3" => (28_000 + i as u64, 199),
        "fisheye-erf4" => (29_000 + i as u64, 211),
        "fisheye-eval7" => (30_000 + i as u64, 223),
        "fisheye-eval8" => (31_000 + i as u64, 227),
        "fisheye-erf5" => (32_000 + i as u64, 229),
        "fisheye-eval9" => (33_000 + i as u64, 233),
        "fisheye-erf6" => (34_000 + i as u64, 239),
        "fisheye-eval10" => (35_000 + i as u64, 241),
        "fisheye-erf7" => (36_000 + i as u64, 251),
        "fisheye-eval11" => (37_000 + i as u64, 257),
        "fisheye-erf8" => (38_000 + i as u64, 263),
        "fisheye-wide" => (39_000 + i as u64, 269),
        _ => (i as u64, 3),
    };
    let mut rng = Rng::new(seed.wrapping_mul(7919).wrapping_add(offset));
    // Fixed responses first (the issue's cases), then alternate EMoR draws and gamma curves.
    let response = match (set, i) {
        ("tuning", 0) => ResponseModel::Emor { c: [0.0; 4] },
        ("tuning", 1) => ResponseModel::Emor {
            c: [-6.0, 0.5, 0.3, 0.0],
        },
        ("tuning", 2) => ResponseModel::Gamma { gamma: 2.4 },
        ("eval", 0) => ResponseModel::Gamma { gamma: 2.6 },
        ("eval", 1) => ResponseModel::Gamma { gamma: 1.0 },
        _ if i % 3 == 2 => ResponseModel::Gamma {
            gamma: 1.0 + 1.6 * rng.uniform(),
        },
        _ => emor_draw(&mut rng),
    };
    let v1 = -0.15 - 0.4 * rng.uniform();
    let vignette = [v1, 0.2 * (rng.uniform() - 0.5), 0.1 * (rng.uniform() - 0.5)];
    let cam = SynthCamera {
        width,
        height,
        response,
        vignette,
        shot: 2e-4,
        read: 1.5e-3,
        sixteen_bit: false,
        seed,
    };
    let mut video = AeVideo {
        mid: 0.03 + 0.06 * rng.uniform(),
        stops: 5.0 + 3.0 * rng.uniform(),
        speed: 0.7 + 0.6 * rng.uniform(),
        ..AeVideo::default()
    };
    video.program = ExposureProgram::AutoExposure {
        target: 0.3 + 0.25 * rng.uniform(),
        gain: 0.3 + 0.5 * rng.uniform(),
        flicker: 0.02 + 0.06 * rng.uniform(),
    };
    if saturated {
        // The tuning split's scene and vignettes with a third to half of the pixels clipped,
        // as on the held-out split's scripted programs: an auto-exposure that aims high, or
        // a manual exposure drifting at random (a program the held-out split does not use).
        video.program = if i.is_multiple_of(2) {
            ExposureProgram::AutoExposure {
                target: 0.62 + 0.2 * rng.uniform(),
                gain: 0.3 + 0.5 * rng.uniform(),
                flicker: 0.02 + 0.06 * rng.uniform(),
            }
        } else {
            ExposureProgram::Walk {
                stops: 0.8 + 0.8 * rng.uniform(),
                step: if i % 4 == 1 {
                    0.05 + 0.1 * rng.uniform()
                } else {
                    0.2 + 0.2 * rng.uniform()
                },
            }
        };
        if i % 4 >= 2 {
            video.scene = SceneForm::Blocks;
        }
        if i.is_multiple_of(3) {
            video.vignette = VignetteForm::Gaussian {
                corner: 0.35 + 0.4 * rng.uniform(),
            };
        }
    }
    if scripted {
        // The held-out split's scripted program forms (a sinusoidal sweep or held random
        // steps around the start exposure; 13–62 % of the pixels clipped) on the tuning scenes and
        // on the scene and vignetting law of `saturated`, never on `eval`'s Voronoi patches or
        // cos⁴ law: the one tuning set where the programs behind `eval`'s misses occur.
        video.program = if i.is_multiple_of(2) {
            ExposureProgram::Sweep {
                stops: 0.5 + 1.0 * rng.uniform(),
                period: 40.0 + 80.0 * rng.uniform(),
                flicker: 0.03,
            }
        } else {
            ExposureProgram::Steps {
                stops: 0.5 + 1.0 * rng.uniform(),
                hold: 5 + (rng.uniform() * 20.0) as usize,
            }
        };
        if i % 4 >= 2 {
            video.scene = SceneForm::Blocks;
        }
        if i.is_multiple_of(3) {
            video.vignette = VignetteForm::Gaussian {
                corner: 0.35 + 0.4 * rng.uniform(),
            };
        }
    }
    if lens {
        // Wide-angle and mechanically vignetted lenses on the tuning scenes and AE programs:
        // a plateau with a steep shoulder (hood, filter ring) or a strong Gaussian fall-off,
        // laws `eval` does not use.
        if i % 4 >= 2 {
            video.scene = SceneForm::Blocks;
        }
        video.vignette = if i % 3 == 2 {
            VignetteForm::Gaussian {
                corner: 0.15 + 0.15 * rng.uniform(),
            }
        } else {
            VignetteForm::Mechanical {
                start: 0.1 + 0.35 * rng.uniform(),
                depth: 0.35 + 0.3 * rng.uniform(),
            }
        };
    }
    if scenes {
        // A scene no other split uses (dead leaves: curved occluding edges at every scale)
        // under the program mix of `eval` (scripted sweeps and steps, and auto-exposure) and
        // polynomial or Gaussian vignetting, never `eval`'s Voronoi patches or cos⁴ law: does
        // the accuracy depend on the scene?
        video.scene = SceneForm::Discs;
        video.program = eval_program_mix(i, &mut rng, video.program);
        if i % 4 < 2 {
            video.vignette = VignetteForm::Gaussian {
                corner: 0.35 + 0.4 * rng.uniform(),
            };
        }
    }
    if eval {
        video.program = eval_program_mix(i, &mut rng, video.program);
        if i.is_multiple_of(2) {
            video.scene = SceneForm::Patches;
        }
        if i % 4 < 2 {
            video.vignette = VignetteForm::Cos4 {
                corner_deg: 30.0 + 15.0 * rng.uniform(),
            };
        }
    }
    if fisheye || fisheye_wide {
        // A fisheye's image circle (tuning): cos⁴ inside a logistic border, nearly black
        // corners, the circle cutting the frame's top and bottom or only its corners; for
        // `fisheye-wide` the border at or past the corners (so that no circle is found) and
        // off-centre by up to ±6 px per axis.
        if i % 4 >= 2 {
            video.scene = SceneForm::Blocks;
        }
        let (r0, dr) = if fisheye_wide {
            (0.9, 0.15)
        } else {
            (0.65, 0.25)
        };
        video.vignette = VignetteForm::FisheyeLogistic {
            corner_deg: 40.0 + 25.0 * rng.uniform(),
            radius: r0 + dr * rng.uniform(),
            width: 0.02 + 0.03 * rng.uniform(),
        };
        if fisheye_wide {
            video.vignette_shift = [12.0 * (rng.uniform() - 0.5), 12.0 * (rng.uniform() - 0.5)];
        }
    }
    if fisheye_eval {
        // Held out: another border law (a raised cosine reaching 0), off-centre, `eval`'s
        // scenes and program mix.
        video.program = eval_program_mix(i, &mut rng, video.program);
        if i.is_multiple_of(2) {
            video.scene = SceneForm::Patches;
        }
        let inner = 0.5 + 0.25 * rng.uniform();
        video.vignette = VignetteForm::FisheyeRaised {
            a: 0.2 + 0.3 * rng.uniform(),
            inner,
            outer: inner + 0.1 + 0.15 * rng.uniform(),
        };
        video.vignette_shift = [12.0 * (rng.uniform() - 0.5), 12.0 * (rng.uniform() - 0.5)];
    }
    if fisheye_erf {
        // Held out: a third circle law (cos³ of an equidistant fisheye's field angle inside a
        // defocused stop's erfc edge), off-centre by up to ±8 px, `eval`'s scenes and programs.
        video.program = eval_program_mix(i, &mut rng, video.program);
        if i.is_multiple_of(2) {
            video.scene = SceneForm::Patches;
        }
        video.vignette = VignetteForm::FisheyeErf {
            corner_deg: 50.0 + 30.0 * rng.uniform(),
            radius: 0.7 + 0.2 * rng.uniform(),
            width: 0.01 + 0.05 * rng.uniform(),
        };
        video.vignette_shift = [16.0 * (rng.uniform() - 0.5), 16.0 * (rng.uniform() - 0.5)];
    }
    if soft {
        // A real lens and sensor are soft at the pixel scale: σ 0.6–2 px of Gaussian blur.
        video.optics_blur = 0.6 + 1.4 * rng.uniform();
    }
    // `SWEEP_BLUR=σ` overrides the lens blur of any split (diagnosis).
    if let Some(b) = std::env::var("SWEEP_BLUR")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
    {
        video.optics_blur = b;
    }
    // `SWEEP_SPEED=k` multiplies the motion of any split (diagnosis: a larger sensor sees the
    // same camera motion as more pixels per frame).
    if let Some(k) = std::env::var("SWEEP_SPEED")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
    {
        video.speed *= k;
    }
    let rname = match &cam.response {
        ResponseModel::Gamma { gamma } => format!("gamma {gamma:.2}"),
        ResponseModel::Emor { c } => format!(
            "emor [{:.2},{:.2},{:.2},{:.2}] f(.5)={:.2}",
            c[0],
            c[1],
            c[2],
            c[3],
            cam.response.forward(0.5)
        ),
    };
    let pname = match &video.program {
        ExposureProgram::AutoExposure { .. } => "ae",
        ExposureProgram::Sweep { .. } => "sweep",
        ExposureProgram::Steps { .. } => "steps",
        ExposureProgram::Walk { .. } => "walk",
    };
    let blur = if video.optics_blur > 0.0 {
        format!(" blur {:.1}", video.optics_blur)
    } else {
        String::new()
    };
    let name = format!(
        "{set}#{i} {rname} {pname} {:?} {}{blur}",
        video.scene,
        match video.vignette {
            VignetteForm::Polynomial => "poly",
            VignetteForm::Cos4 { .. } => "cos4",
            VignetteForm::Gaussian { .. } => "gauss",
            VignetteForm::Mechanical { .. } => "mech",
            VignetteForm::FisheyeLogistic { .. }
            | VignetteForm::FisheyeRaised { .. }
            | VignetteForm::FisheyeErf { .. } => "fisheye",
        }
    );
    (name, cam, video)
}

/// CPU seconds of this process (user + system, Linux `/proc/self/stat`; NaN elsewhere): wall
/// time is meaningless on a loaded machine, CPU time divided by the cores used is not.
fn cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1;
            let f: Vec<&str> = rest.split_whitespace().collect();
            let u: f64 = f.get(11)?.parse().ok()?;
            let k: f64 = f.get(12)?.parse().ok()?;
            Some((u + k) / 100.0)
        })
        .unwrap_or(f64::NAN)
}

/// Records the CPU and wall time at which each named stage starts.
struct Stages(std::sync::Mutex<Vec<(String, f64, Instant)>>);

impl caliper_core::Progress for Stages {
    fn report(&self, step: &str, _: u64, _: u64) {
        if let Ok(mut s) = self.0.lock()
            && s.last().is_none_or(|l| l.0 != step)
        {
            s.push((step.to_string(), cpu_seconds(), Instant::now()));
        }
    }
    fn is_canceled(&self) -> bool {
        false
    }
}

fn score(
    name: String,
    frames: &[PhotoImage],
    truth_inv: &InverseResponse,
    truth_vig: &[f32],
    truth_e: &[f64],
    truth_center: [f64; 2],
) -> Row {
    let (t0, c0) = (Instant::now(), cpu_seconds());
    // `SWEEP_PARAMS='{"gamma_gauge": 0.5}'` reproduces the old fixed gauge.
    let params: OnlineParams = std::env::var("SWEEP_PARAMS")
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or_default();
    let stages = Stages(std::sync::Mutex::new(Vec::new()));
    let res = photometric_online(frames, &params, &stages);
    let secs = t0.elapsed().as_secs_f64();
    let cpu = cpu_seconds() - c0;
    match res {
        Ok(r) => {
            let fit = InverseResponse {
                values: r.model.inverse_256.clone(),
            };
            let (alpha, resp) = gamma_align(&fit, truth_inv);
            let vmap = r
                .model
                .vignette
                .as_ref()
                .map(|v| v.map())
                .unwrap_or_default();
            if std::env::var_os("SWEEP_RADIAL").is_some()
                && let Some(sp) = r.model.vignette.as_ref().and_then(|v| v.spline.as_ref())
            {
                let v: Vec<String> = sp.values.iter().map(|v| format!("{v:.3}")).collect();
                println!("    spline values: {}", v.join(" "));
            }
            let vig = vignette_rmse_inside(&vmap, truth_vig, alpha);
            let exp0 = exposure_error_pct(&r.exposure_ratios, truth_e, alpha);
            // The shared score's exposure error: with the best common scale, not frame 0's.
            // A video fitted in parts (`broken_tracks: per_part`): each part's own scale.
            let exp = match &r.exposure_parts {
                Some(parts) => exposure_error_parts_pct(&r.exposure_ratios, truth_e, alpha, parts),
                None => exposure_error_common_pct(&r.exposure_ratios, truth_e, alpha),
            };
            let d: Vec<f64> = r
                .exposure_ratios
                .iter()
                .zip(truth_e)
                .map(|(f, t)| alpha * f.ln() - t.ln())
                .collect();
            let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
            if std::env::var_os("SWEEP_FRAMES").is_some() {
                let per: Vec<String> = d
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| {
                        *i < 8 || (std::env::var_os("SWEEP_ALL").is_some() && i % 10 == 0)
                    })
                    .map(|(i, x)| format!("{:+.1}%@{:.2}", 100.0 * (x - mean).exp_m1(), truth_e[i]))
                    .collect();
                println!("    first frames vs common scale: {}", per.join(" "));
            }
            let (lo, hi) = truth_e
                .iter()
                .fold((f64::MAX, 0.0f64), |a, &e| (a.0.min(e), a.1.max(e)));
            let sat = clipped_fraction(frames);
            println!(
                "{name:70} resp {resp:.4} vig {vig:.4} exp {exp:5.2}% (vs frame 0 {exp0:.2}%) α {alpha:.3} {secs:.2}s cpu {cpu:.2}s it {} rms {:.2} f(.5) {:.3} e {lo:.2}..{hi:.2} sat {:.1}%",
                r.diagnostics.iterations,
                r.diagnostics.residual_rms_levels,
                r.model.response.forward(0.5),
                100.0 * sat
            );
            if r.exposure_parts.is_some() {
                let n = r.exposure_part_count();
                println!("    fitted in {n} parts (broken tracks), exposures scored per part");
            }
            println!(
                "    vignette: {} ({}); tracking passes fitted: {}",
                r.vignette_choice.model, r.vignette_choice.reason, r.tracking_passes
            );
            if let Some(c) = &r.image_circle {
                println!(
                    "    image circle found: centre ({:.1}, {:.1}) radius {:.1} px, {} points, RMS {:.2} px",
                    c.center[0], c.center[1], c.radius_px, c.border_points, c.rms_px
                );
                let v = &r.vignette_center;
                println!(
                    "    vignetting centre ({:.1}, {:.1}), {:.2} px from the truth: {}",
                    v.center[0],
                    v.center[1],
                    (v.center[0] - truth_center[0]).hypot(v.center[1] - truth_center[1]),
                    v.reason
                );
            }
            if let Some(m) = r.measured_levels {
                // The share of the camera's (normalised) irradiance range above the brightest
                // measured level: what the response there extrapolates.
                let t = truth_inv.normalized_1_254();
                let i = (m.high.round() as usize).clamp(1, 254) - 1;
                println!(
                    "    measured levels {:.0}–{:.0}; truth's irradiance above them {:.2}",
                    m.low,
                    m.high,
                    1.0 - t[i]
                );
            }
            if std::env::var_os("SWEEP_STAGES").is_some()
                && let Ok(s) = stages.0.lock()
            {
                let st: Vec<String> = s
                    .iter()
                    .map(|(n, t, i)| format!("{n}@{:.2}/{:.2}", t - c0, (*i - t0).as_secs_f64()))
                    .collect();
                println!("    stages (cpu s / wall s): {}", st.join(" "));
            }
            Row {
                name,
                resp,
                vig,
                exp,
                exp0,
                secs,
            }
        }
        Err(e) => {
            println!("{name:70} FAILED: {e}");
            Row {
                name,
                resp: f64::INFINITY,
                vig: f64::INFINITY,
                exp: f64::INFINITY,
                exp0: f64::INFINITY,
                secs,
            }
        }
    }
}

/// [`vignette_rmse`] over the image circle: the pixels where the truth is at least
/// [`CIRCLE`] of its maximum (every pixel of a lens without an image circle). Prints the share
/// of those pixels the fit masked (0 in its map) when there is any.
fn vignette_rmse_inside(fit: &[f32], truth: &[f32], alpha: f64) -> f64 {
    let tm = truth.iter().copied().fold(0.0f32, f32::max).max(1e-30);
    let inside: Vec<usize> = (0..truth.len())
        .filter(|&i| truth[i] >= CIRCLE * tm)
        .collect();
    if inside.len() == truth.len() || fit.len() != truth.len() {
        return vignette_rmse(fit, truth, alpha);
    }
    let masked = inside.iter().filter(|&&i| fit[i] <= 0.0).count();
    let outside_kept = (0..truth.len())
        .filter(|&i| truth[i] < 0.01 * tm && fit[i] > 0.0)
        .count();
    println!(
        "    image circle: {} of {} pixels inside; fit masks {masked} of them and keeps {outside_kept} of the {} below 1 %",
        inside.len(),
        truth.len(),
        truth.iter().filter(|&&t| t < 0.01 * tm).count()
    );
    let pick = |v: &[f32]| inside.iter().map(|&i| v[i]).collect::<Vec<f32>>();
    if std::env::var_os("SWEEP_RADIAL").is_some() {
        print_error_by_level(&pick(fit), &pick(truth), alpha);
    }
    vignette_rmse(&pick(fit), &pick(truth), alpha)
}

/// `SWEEP_RADIAL=1` (diagnosis): the vignette's error split by the true attenuation's level
/// (both maps normalised to maximum 1 as [`vignette_rmse`] does), so that a miss shows whether
/// it lies on the border or inside: per band the pixel count, RMSE and mean signed error.
fn print_error_by_level(fit: &[f32], truth: &[f32], alpha: f64) {
    let (f, t) = aligned_maps(fit, truth, alpha);
    let bands = [0.0, 0.25, 0.5, 0.8, 1.01];
    let mut out = Vec::new();
    for b in bands.windows(2) {
        let (mut n, mut s2, mut s1) = (0usize, 0.0, 0.0);
        for (&fv, &t) in f.iter().zip(&t) {
            if t >= b[0] && t < b[1] {
                let e = fv - t;
                n += 1;
                s2 += e * e;
                s1 += e;
            }
        }
        let d = n.max(1) as f64;
        out.push(format!(
            "[{:.2},{:.2}) n {n} rmse {:.4} bias {:+.4}",
            b[0],
            b[1].min(1.0),
            (s2 / d).sqrt(),
            s1 / d
        ));
    }
    println!("    vignette error by true level: {}", out.join(" | "));
}

/// Where a fisheye's image circle ends for scoring (the offline fisheye tests' bound).
const CIRCLE: f32 = 0.05;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Every frame of a clip (`SWEEP_CLIP`, e.g. the shared frames re-encoded at another quality
/// with `ffmpeg -framerate 20 -i images/%06d.png -c:v libx264 -crf 23 -pix_fmt yuv420p`, or a
/// `SWEEP_CRF` encode), its luma read in the range the clip signals as the service's clip path
/// does, and the clip's coded bits per pixel. Needs the `video` feature (`--features video`).
#[cfg(feature = "video")]
fn clip_frames(path: &Path) -> Result<(Vec<PhotoImage>, f64), String> {
    use caliper_core::video::{FrameFormat, FrameOptions, FrameReader, VideoLimits};
    let file = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let options = FrameOptions {
        format: FrameFormat::Luma,
        ..FrameOptions::default()
    };
    let mut reader = FrameReader::open(
        std::io::BufReader::new(file),
        &VideoLimits::default(),
        options,
    )
    .map_err(|e| e.to_string())?;
    // The range the clip signals, as the service's `luma_range: auto` reads it.
    let full = reader.info().full_range == Some(true);
    let bits_per_pixel = reader.info().bits_per_pixel;
    let mut out = Vec::new();
    while let Some(frame) = reader.next_frame() {
        let g = frame.map_err(|e| e.to_string())?.image.into_luma();
        let (w, h) = g.dimensions();
        out.push(PhotoImage::from_video_luma(
            w as usize,
            h as usize,
            g.into_raw(),
            full,
        ));
    }
    Ok((out, bits_per_pixel))
}

#[cfg(not(feature = "video"))]
fn clip_frames(_: &Path) -> Result<(Vec<PhotoImage>, f64), String> {
    Err("SWEEP_CLIP and SWEEP_CRF need the example built with `--features video`".into())
}

/// `SWEEP_CRF=N`: a rendered case as a phone or action camera would hand it over, H.264
/// (x264 High, yuv420p, 20 fps, constant rate factor N, `SWEEP_X264` extra options) through
/// `ffmpeg` on `PATH`, decoded as the service decodes a clip. Returns the decoded frames and
/// the clip's bits per pixel.
fn encode_case(
    frames: &[PhotoImage],
    crf: &str,
    tag: &str,
) -> Result<(Vec<PhotoImage>, f64), String> {
    use std::io::Write;
    let first = frames.first().ok_or("no frames")?;
    if first.max_level != 255 {
        return Err("SWEEP_CRF needs 8-bit frames".into());
    }
    // `SWEEP_CRF=mjpeg:Q`: Motion-JPEG at ffmpeg's quality scale Q (2 best … 31) in a QuickTime
    // file, as USB cameras deliver it.
    let mjpeg = crf.strip_prefix("mjpeg:");
    let ext = if mjpeg.is_some() { "mov" } else { "mp4" };
    let out =
        std::env::temp_dir().join(format!("caliper-sweep-{}-{tag}.{ext}", std::process::id()));
    let size = format!("{}x{}", first.width, first.height);
    let mut args = vec![
        "-loglevel",
        "error",
        "-y",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "gray",
        "-s",
        &size,
        "-framerate",
        "20",
        "-i",
        "-",
    ];
    match mjpeg {
        Some(q) => args.extend(["-c:v", "mjpeg", "-pix_fmt", "yuvj420p", "-q:v", q]),
        None => args.extend([
            "-c:v",
            "libx264",
            "-profile:v",
            "high",
            "-pix_fmt",
            "yuv420p",
            "-crf",
            crf,
        ]),
    }
    let extra = std::env::var("SWEEP_X264").unwrap_or_default();
    args.extend(extra.split_whitespace());
    let out_str = out.to_string_lossy().into_owned();
    args.push(&out_str);
    let mut child = std::process::Command::new("ffmpeg")
        .args(&args)
        .stdin(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| format!("ffmpeg: {e}"))?;
    {
        let mut stdin = child.stdin.take().ok_or("ffmpeg: no stdin")?;
        for f in frames {
            let px: Vec<u8> = f.data.iter().map(|&v| v as u8).collect();
            stdin.write_all(&px).map_err(|e| format!("ffmpeg: {e}"))?;
        }
    }
    let status = child.wait().map_err(|e| format!("ffmpeg: {e}"))?;
    if !status.success() {
        return Err(format!("ffmpeg failed: {status}"));
    }
    let (decoded, bpp) = clip_frames(&out)?;
    let _ = std::fs::remove_file(&out);
    Ok((decoded, bpp))
}

fn shared(dir: &Path) -> Result<Row, String> {
    let read = |p: PathBuf| std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()));
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir.join("images"))
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    paths.sort();
    let frames = match std::env::var_os("SWEEP_CLIP") {
        Some(clip) => clip_frames(Path::new(&clip))?.0,
        None => paths
            .into_iter()
            .map(|p| {
                PhotoImage::decode(&read(p)?, &ImageLimits::default()).map_err(|e| e.to_string())
            })
            .collect::<Result<Vec<_>, _>>()?,
    };
    let gt: serde_json::Value =
        serde_json::from_slice(&read(dir.join("gt.json"))?).map_err(|e| format!("gt.json: {e}"))?;
    let f64s = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .map(|a| a.iter().filter_map(serde_json::Value::as_f64).collect())
            .unwrap_or_default()
    };
    let truth_inv = InverseResponse {
        values: f64s(&gt["response"]["inverse_256"]),
    };
    let truth_e = f64s(&gt["exposure_ratio_to_frame0"]);
    let vig = read_vignette_png(
        &read(dir.join("vignette.png"))?,
        &ImageLimits::default(),
        None,
    )
    .map_err(|e| e.to_string())?;
    // The shared sequence's vignetting is centred (it has no image circle either).
    let center = frames
        .first()
        .map_or([0.0; 2], |f| [f.width as f64 / 2.0, f.height as f64 / 2.0]);
    Ok(score(
        "ae_seq_seed0".into(),
        &frames,
        &truth_inv,
        &vig.data,
        &truth_e,
        center,
    ))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let set = args.first().map_or("tuning", String::as_str).to_string();
    let num = |i: usize, d: usize| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    if set == "shared" {
        let dir = std::env::var_os("CALIPER_PHOTO_DATA").map_or_else(
            || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/photometric"),
            PathBuf::from,
        );
        if let Err(e) = shared(&dir.join("ae_seq_seed0")) {
            eprintln!("photometric_sweep: {e}");
            std::process::exit(1);
        }
        return;
    }
    let (cases, frames, width, height) = (num(1, 12), num(2, 200), num(3, 320), num(4, 240));
    let only: Option<usize> = args.get(5).and_then(|s| s.parse().ok());
    let mut rows = Vec::new();
    for i in 0..cases {
        if only.is_some_and(|o| o != i) {
            continue;
        }
        let (name, cam, video) = case(&set, i, width, height);
        // `SWEEP_VIDEO=default` renders every case with the shared data's scene and program.
        let video = if std::env::var("SWEEP_VIDEO").is_ok_and(|v| v == "default") {
            AeVideo::default()
        } else {
            video
        };
        let true_center = [
            width as f64 / 2.0 + video.vignette_shift[0],
            height as f64 / 2.0 + video.vignette_shift[1],
        ];
        if std::env::var_os("SWEEP_DEBUG").is_some() {
            let c = true_center;
            eprintln!(
                "{name}\n  {cam:?}\n  {video:?}\n  true vignetting centre ({:.2}, {:.2})",
                c[0], c[1]
            );
        }
        let seq = render_ae_video(&cam, frames, &video);
        if let (Ok(dir), Some(f)) = (std::env::var("SWEEP_DUMP"), seq.frames.first()) {
            // The first frame as an 8-bit PNG, to look at the scene.
            let px: Vec<u8> = f
                .data
                .iter()
                .map(|&v| (f64::from(v) * 255.0 / f64::from(f.max_level)).round() as u8)
                .collect();
            let _ = image::GrayImage::from_raw(f.width as u32, f.height as u32, px)
                .map(|g| g.save(format!("{dir}/{set}_{i}.png")));
        }
        let (name, frames) = match std::env::var("SWEEP_CRF") {
            Ok(crf) => match encode_case(&seq.frames, &crf, &i.to_string()) {
                Ok((decoded, bpp)) => (format!("{name} crf {crf} bpp {bpp:.3}"), decoded),
                Err(e) => {
                    eprintln!("photometric_sweep: {name}: {e}");
                    std::process::exit(1);
                }
            },
            Err(_) => (name, seq.frames.clone()),
        };
        rows.push(score(
            name,
            &frames,
            &cam.response.inverse(256),
            &seq.vignette_map,
            &seq.exposures,
            true_center,
        ));
    }
    let col = |f: fn(&Row) -> f64| rows.iter().map(f).collect::<Vec<_>>();
    let worst = |f: fn(&Row) -> f64| {
        rows.iter()
            .max_by(|a, b| f(a).total_cmp(&f(b)))
            .map_or(String::new(), |r| format!("{:.4} ({})", f(r), r.name))
    };
    println!(
        "\n{set}: {} cases, {frames} frames {width}×{height}",
        rows.len()
    );
    println!(
        "response RMSE median {:.4} worst {}",
        median(col(|r| r.resp)),
        worst(|r| r.resp)
    );
    println!(
        "vignette RMSE median {:.4} worst {}",
        median(col(|r| r.vig)),
        worst(|r| r.vig)
    );
    println!(
        "exposure err% median {:.3} worst {} (best common scale, as score_ref.json)",
        median(col(|r| r.exp)),
        worst(|r| r.exp)
    );
    println!(
        "  vs frame 0   median {:.3} worst {}",
        median(col(|r| r.exp0)),
        worst(|r| r.exp0)
    );
    println!(
        "time s        median {:.2} worst {}",
        median(col(|r| r.secs)),
        worst(|r| r.secs)
    );
    let pass = rows
        .iter()
        .filter(|r| r.resp < 0.005 && r.vig < 0.01 && r.exp < 2.0 && r.secs <= 10.0)
        .count();
    println!("targets met on {pass}/{} cases", rows.len());
}
