//! Dense refinement: the face-space fit carried past the landmarks by the photos' pixels.
//!
//! The landmark fit ([`FaceSpace::fit_photos`]) sees 40 points per photo; the shape between
//! them is the space's prior. [`FaceSpace::refine_photos`] adds what the photos themselves
//! say: the surface is sampled over the face region, every sample is projected into every
//! photo that sees it, and the identity weights and cameras move until the photos agree with
//! each other about what lies at each sample (photo-consistency), while the landmarks and the
//! prior still hold.
//!
//! # The objective
//!
//! ```text
//! E(w, cameras) = Σᵢⱼ ωⱼ ‖πᵢ(Sⱼ(w) + Eⱼ eᵢ) − xᵢⱼ‖² / (uᵢ ε)²                  landmarks
//!               + β Σₛ Σᵢ cᵢₛ ρ(Nᵢ(πᵢ(Fₛ(w) + Gₛ eᵢ)) − μₛ) / σ²                consistency
//!               + Σₖ wₖ² / σₖ²  +  Σᵢ (κᵢ − κ̄ᵢ)² / (0.7 κ̄ᵢ)²                       priors
//! ```
//!
//! * `πᵢ` is photo `i`'s camera ([`RefinedCamera`]): a pinhole camera with its principal
//!   point at the image's centre, `x = c + (o − c + s · P R X) / (1 − κ (R X)_z)`, the landmark
//!   fit's scaled orthographic camera with a perspective term `κ = 1/d` (`d` the camera's
//!   distance, canonical units): near cameras magnify the nose. A photo's distance is poorly
//!   seen in its pixels (a nearer camera and a deeper face look alike), so `κᵢ` starts at, and
//!   is drawn toward, `κ̄ᵢ = sᵢ / f` for a typical focal length `f` ([`TYPICAL_FOCAL`]).
//! * `Nᵢ` is photo `i`'s grey intensity made comparable with the other photos'. How is the
//!   choice the method leaves open (normalised cross-correlation of patches, or colour after
//!   a per-photo gain and bias; [`RefineOptions::window`]). By default ([`Window::Lit`]) it is
//!   analysis by synthesis: the intensity made linear, divided by the photo's shading (a
//!   first-order spherical-harmonic light per photo, fitted with an albedo per sample shared
//!   by the photos, over the **current shape's own normals**), then scaled by a gain and bias
//!   per photo. The shading that a light from another side in each photo casts is explained
//!   by the shape rather than removed, so it says where the surface turns: a nose's depth
//!   shows in how fast its side darkens. Alternatively the intensity is **locally
//!   normalised**: its local mean removed and divided by its local deviation over a Gaussian
//!   window of [`RefineOptions::window_eyes`] eye distances, so that smooth shading cancels and
//!   texture and edges (eyes, brows, nostrils, lips, skin detail) remain; the window lies in
//!   each photo's image ([`Window::Image`], the former default) or on the surface
//!   ([`Window::Surface`], about each sample over the samples the photo sees, held fixed
//!   while a step is solved for and recomputed wherever the cost is taken), optionally of the
//!   intensities with each photo's shading over the mean face's normals divided out
//!   ([`Window::Shaded`]). Started from the true face, every window refined it away from the
//!   truth, to faces on which the photos agreed better than on the truth; the lit measure
//!   is the one measured to prefer the truth (on 11 of 12 sets,
//!   `tools/results/from-truth-lit.md`), and it is the better on the photo-realistic
//!   evaluation ([`RefineOptions::default`]).
//! * `μₛ` is the weighted mean over the views that see sample `s` (the unknown albedo,
//!   eliminated exactly: the Jacobian of each residual has the views' mean Jacobian taken
//!   off); `cᵢₛ` is how squarely photo `i` sees the sample (0 when it faces away or lies behind
//!   another part of the face: a depth test against the samples themselves in that view);
//!   `ρ` a Cauchy loss (shadows, highlights and hair disagree for reasons other than shape).
//! * `Fₛ(w)`, `Sⱼ(w)` are the space's surface at sample `s` and its structure point `j`;
//!   `Gₛ`, `Eⱼ` the photo's expression (fixed at the landmark fit's).
//! * At the finest level a depth displacement `d` of the control grid joins the unknowns
//!   ([`RefineOptions::field`], on by default): the sample becomes `Fₛ(w) + Σₑ βₛₑ dₑ z`
//!   (`βₛₑ` the surface's basis values at the sample; the normals stay the space's), and the
//!   priors gain `Σ (Δ²d / b)² + Σₑ (dₑ / s)²`, the grid's second differences along rows,
//!   columns and across under [`RefineOptions::field_bend`] and a ridge under
//!   [`RefineOptions::field_sigma`].
//!
//! Gauss-Newton with Levenberg–Marquardt damping, coarse to fine over image scales
//! ([`RefineOptions::levels`]): at each level the photos are cropped about the face and
//! resampled to the level's eye distance in pixels, so that the surface samples and the
//! pixels keep the same ratio whatever the photos' sizes.
//!
//! # When the photos do not agree
//!
//! The result is kept only when the photos agree better on the refined face than on the
//! landmark fit's (their disagreement at the finest level falls by
//! [`RefineOptions::min_gain`] or more) and, when asked, photos the refinement did not see
//! agree better with it too ([`RefineOptions::held_out`], below) and the landmarks still fit
//! (their RMS grows by at most [`RefineOptions::landmark_slack`] units); neither is checked by
//! default. Otherwise the landmark result stands and [`Refinement::accepted`] says why not.
//! A fall short of [`RefineOptions::full_gain`] keeps only part of the way from the landmark
//! fit to the refined face, in proportion ([`Refinement::share`]).
//!
//! The photos' agreement is what the refinement minimises, so its fall says little about
//! whether the face came nearer the truth: a face bent to fit the photos' noise, or one that
//! trades one part of the face for another, also agrees better. The check on photos left out
//! is a cross-validation: the photos are ordered by yaw and dealt into folds (two for four
//! photos or more, one photo at a time for three; none for two), and for each fold the
//! other photos refine the face (the fold's photos count only by their landmarks) while,
//! for comparison, the same photos refine only the cameras of the landmark fit's face. On
//! each face the fold's photos are aligned by their pixels to the others (the face and the
//! others' cameras held) and compared with the others' mean intensity at every sample; the
//! refinement is kept only if the refined face explains them at least as well (a fall of
//! [`RefineOptions::min_held_out_gain`]). The folds run at every level but the finest, only
//! where the refinement would otherwise be kept. Measured, it tells harmful refinements
//! from helpful ones too poorly to be the default ([`RefineOptions::held_out`]). Within
//! a refinement, a photo that disagrees with the others more than most (another light, an
//! expression, make-up) can be made to count less ([`RefineOptions::photo_weights`]).

use nalgebra::{DMatrix, DVector, Matrix2x3, Point2, Point3, Rotation3, SVector, Vector2, Vector3};
use rayon::prelude::*;

use super::FaceError;
use super::space::{FaceSpace, PhotoSpaceFit, add_weighted};
use crate::Real;
use crate::align::GreyImage;
use crate::reference::ReferenceFace;
use crate::structure::POINT_COUNT;
use equations::Equations;

mod equations;

/// The local normalisation's window (Gaussian deviation), in eye distances.
pub const NORMALISATION_EYES: Real = 0.12;

/// Options of [`FaceSpace::refine_photos`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineOptions {
    /// The number of levels, coarse to fine; each halves the previous one's eye distance in
    /// pixels and doubles its samples' spacing.
    pub levels: usize,
    /// The finest level's eye distance in pixels (a photo with fewer is seen at its own size).
    pub eye_pixels: Real,
    /// The finest level's spacing of the surface samples, canonical units (50 between the eye
    /// centres).
    pub spacing: Real,
    /// Gauss-Newton iterations per level at most (a level also stops when a step gains less
    /// than 10⁻⁴ of the cost; 10⁻⁵ when the table below was measured). 16 by default.
    /// Measured by `tools/photo_eval` (the same pools and sets, `--methods "default,refine
    /// iterations 8,landmarks only"` and the variants below; mean ratio of the error to the
    /// mean face's for 2 / 3 / 4 / 8 / 16 photos, and to the landmark fit's over the 105 sets
    /// scored):
    ///
    /// | variant | 2 | 3 | 4 | 8 | 16 | to the landmark fit | sets > 2% worse than it |
    /// |---|---|---|---|---|---|---|---|
    /// | 8 iterations (the former default) | 0.86 | 0.77 | 0.74 | 0.74 | 0.69 | 0.838 | 8 |
    /// | **16 iterations** | 0.85 | 0.77 | 0.74 | 0.72 | 0.69 | 0.833 | 8 |
    ///
    /// Against 8 iterations, 26 sets came out better by more than 0.005 mm and 13 worse; the
    /// refinement of eight photos of the scan took 135–250 ms against 100–160 ms. On the 3-
    /// and 8-photo sets (44; to the landmark fit, sets more than 2% worse than it, the worst):
    /// a fourth, finer level (160 pixels between the eyes, samples 1 unit apart) 0.799, 5,
    /// 1.37 against the default's 0.839, 3, 1.11; three levels with samples 1 unit apart at the
    /// finest 0.819, 8, 1.39: finer samples gain on most faces and cost more on the few the
    /// refinement already made worse, and take two to six times as long. A finer eye distance
    /// alone (120 pixels) changed nothing: the evaluation's photos show the eyes less than 80
    /// pixels apart, and each photo is seen at most at its own size.
    pub iterations: usize,
    /// `σ`: the spread of a normalised intensity between photos that agree.
    pub sigma: Real,
    /// `β`: the weight of one consistency residual against one landmark coordinate (the
    /// samples are not independent: neighbours see overlapping pixels).
    pub beta: Real,
    /// `ε`, the landmarks' error per coordinate (canonical units), as in
    /// [`super::PhotoFitOptions::noise`].
    pub noise: Real,
    /// Refine each photo's perspective `κ` (else the cameras stay scaled orthographic).
    pub perspective: bool,
    /// How the photos' intensities are made comparable: compared with the face lit
    /// ([`Window::Lit`], the default), or locally normalised over a window ([`Window`]).
    pub window: Window,
    /// The local normalisation window's Gaussian deviation, eye distances
    /// ([`NORMALISATION_EYES`] by default). Wider windows take in more of each photo's
    /// shading: with the window in the image, 0.25 and 0.5 eye distances moved the refined
    /// faces further from the truth (mean ratio to the mean face 0.86 and 0.89 against 0.74 on
    /// twelve sets of the ICT identities, `tools/results/from-truth.md`). Unused by
    /// [`Window::Lit`], which has no window.
    pub window_eyes: Real,
    /// Also fit a depth displacement of every control point (the detail the space cannot
    /// carry), held by a thin-plate smoothness ([`RefineOptions::field_bend`]) and a ridge
    /// ([`RefineOptions::field_sigma`]), at the finest [`RefineOptions::field_levels`]
    /// levels. On by default. With the lit measure the field moves the sampled points alone:
    /// its lift is left out of the normals that shade the face, in the cost and the Jacobian
    /// alike (`Samples::shape_normals`). Its unknowns (one per control point, 1024 for the
    /// 32 × 32 grid) are solved for through their banded block's Schur complement
    /// (`equations.rs`).
    ///
    /// Measured by `cargo run --release --example photo_eval -- --methods "default,refine no
    /// field,landmarks only"` and `--methods "default,refine field all levels"` (105 scored
    /// sets; the mean ratio to the mean face's error for 2 / 3 / 4 / 8 / 16 photos; to the
    /// landmark fit's, the sets more than 2% worse than it, the worst; the scan's given sets;
    /// the largest distance between two halves of 16 photos of one subject):
    ///
    /// | field | 2 | 3 | 4 | 8 | 16 | to the landmark fit | worse | worst | photos-8, photos-3 | halves |
    /// |---|---|---|---|---|---|---|---|---|---|---|
    /// | none (the default before) | 0.79 | 0.72 | 0.71 | 0.71 | 0.70 | 0.806 | 5 | 1.18 | 0.90, 0.80 | 0.79 mm |
    /// | at every level | 0.80 | 0.72 | 0.70 | 0.67 | 0.62 | 0.777 | 5 | 1.21 | 0.83, 0.77 | 0.72 mm |
    /// | **at the finest level** | 0.78 | 0.72 | 0.70 | 0.66 | 0.62 | 0.773 | 4 | 1.15 | 0.83, 0.78 | 0.70 mm |
    ///
    /// At the coarser levels (200 and 800 samples against the field's 1024 unknowns, the
    /// photos blurred to 20 and 40 pixels between the eyes) the photos cannot see what the
    /// field would carry; fitted there it only follows their noise. The field costs the real
    /// scan's 16-photo sets a little (0.79 / 0.80 / 0.80 against 0.78 / 0.77 / 0.75 without it)
    /// and `reconstruct` of `lps-head/photos-8` about a fifth of a second (the refinement 450
    /// ms against 256, the whole 1.16 s against 0.99, `tools/ab-bench`, best of four each).
    ///
    /// Measured and dropped: with the window in the image the field made faces worse (0.769
    /// against 0.754 of the mean face over every set, 12 sets more than 2% worse than the
    /// landmark fit as without it); letting the field tilt the normals under the lit measure
    /// (its lift in the shading and the Jacobian, exact) gave 0.78 / 0.71 / 0.74 / 0.76 / 0.83,
    /// 0.853 of the landmark fit, 12 sets more than 2% worse (the worst 1.44): the field then
    /// bends the surface to explain the light (shadows, sheen) instead of the photos'
    /// agreement.
    ///
    /// A finer grid for the field was measured and dropped too: the reference and its space
    /// refined by knot insertion ([`ReferenceFace::refine_knots`]: the same faces, more
    /// control points) before the pipeline runs, one knot in the middle of every span of the
    /// inner face (`u` 0.2–0.8, `v` 0.15–0.78: 49 × 49 control points) or of every span (61 ×
    /// 61); `photo_eval --methods "refine finer inner,refine finer all"` and `"refine finer
    /// inner bend 0.75"` (the bend's deviation scaled to the halved spacing), each with
    /// `--baseline tools/results/photos.md` (the committed run; the 105 sets set by set):
    ///
    /// | grid | 2 | 3 | 4 | 8 | 16 | mean | to the landmark fit | worse | the scan's 15 sets | photos-8 |
    /// |---|---|---|---|---|---|---|---|---|---|---|
    /// | **32 × 32** | 0.78 | 0.72 | 0.70 | 0.66 | 0.62 | 0.694 | 0.773 | 4 | 0.834 | 0.83 |
    /// | inner face 49 × 49 | 0.79 | 0.72 | 0.70 | 0.68 | 0.63 | 0.702 | 0.781 | 5 | 0.828 | 0.86 |
    /// | the same, bend 0.75 | 0.79 | 0.72 | 0.70 | 0.70 | 0.64 | 0.709 | 0.789 | 5 | 0.831 | 0.88 |
    /// | every span 61 × 61 | 0.78 | 0.72 | 0.70 | 0.68 | 0.64 | 0.703 | 0.783 | 6 | 0.832 | 0.87 |
    ///
    /// More freedom where the photos are compared lets the field follow more of what the lit
    /// measure cannot explain; the grid is not what limits the refinement (its measure is,
    /// `tools/results/from-truth-lit.md`), so knots are not added where the photos disagree
    /// either.
    pub field: bool,
    /// At how many of the finest levels the field is fitted (at least 1; more than
    /// [`RefineOptions::levels`] means every level), from zero where it joins; the coarser
    /// levels fit the space and the cameras alone. 1 by default ([`RefineOptions::field`] has
    /// the figures).
    pub field_levels: usize,
    /// The deviation of one second difference of the displacement grid, canonical units (3
    /// by default). Measured with the field at the finest level (`photo_eval --methods
    /// "refine field bend 1.5,refine field bend 6"`; the mean ratio to the landmark fit's
    /// error over the 105 sets, the sets more than 2% worse than it, `lps-head/photos-8`, the
    /// halves' largest distance): 1.5 gave 0.779, 4, 0.86×, 0.70 mm; 3 gives 0.773, 4, 0.83×,
    /// 0.70 mm; 6 gave 0.775, 6, 0.83×, 0.70 mm.
    pub field_bend: Real,
    /// The prior deviation of one control point's displacement, canonical units (10 by
    /// default). Measured as [`RefineOptions::field_bend`] (`"refine field sigma 3,refine
    /// field sigma 30"`): 3 gave 0.796, 5, 0.89×, 0.79 mm (8 / 16 photos 0.71 / 0.67 of the
    /// mean face); 10 gives 0.773, 4, 0.83×, 0.70 mm (0.66 / 0.62); 30 gave 0.777, 7 (the worst
    /// 1.26), 0.83×, 0.94 mm (0.67 / 0.63).
    pub field_sigma: Real,
    /// The smallest relative fall of the disagreement for which the refinement is kept.
    pub min_gain: Real,
    /// The relative fall of the disagreement from which the refinement is kept whole. Between
    /// [`RefineOptions::min_gain`] and this, the face moves from the landmark fit toward the
    /// refined one in proportion to the fall ([`Refinement::share`]: the identity weights and
    /// any displacement field blended, the refined cameras kept). At or below `min_gain`, or
    /// with `min_gain` not finite, the gate is a step: kept whole or not at all. See
    /// [`RefineOptions::default`] for what was measured.
    pub full_gain: Real,
    /// Weigh each photo by how well it agrees with the others at the start of each level:
    /// `min(1, median / msdᵢ)`, `msdᵢ` its mean squared disagreement about the samples'
    /// means, so that one that disagrees more than the median photo counts less. Off by
    /// default: on `tools/photo_eval` it changed the mean ratio to the mean face by at most
    /// 0.02 per photo count (0.87 / 0.77 / 0.77 / 0.71 / 0.67 against the default's 0.87 /
    /// 0.76 / 0.77 / 0.70 / 0.69), made 11 sets more than 2% worse than the landmark fit
    /// (the default 12), and brought ict-5's two halves of 16 photos from 0.81 to 0.68 mm
    /// apart; a photo with inverted intensities among three good ones is down-weighted
    /// enough to give back the good photos' face (`tests/splineface/refine.rs`).
    ///
    /// Built and measured with the window in the image ([`Window::Image`]). With the lit
    /// measure each photo's light is fitted at full weight (its weight is how far its
    /// intensities are trusted for the shape; its light is its own either way). Fitted at the
    /// photos' weights, as before, a down-weighted photo's light was all but free: five faces
    /// with three good photos and an inverted fourth (`tests/splineface/refine.rs`) ended 1.46
    /// units from the truth on average weighted (the worst 2.38), 0.91 unweighted; with the
    /// lights at full weight, 1.00 (the worst 1.41). On the main evaluation (`photo_eval
    /// --methods "refine photo weights" --baseline tools/results/photos.md`, the 105 sets
    /// set by set against the committed run; mean ratio to the mean face for 2 / 3 / 4 / 8 / 16 photos,
    /// the worst set of each count, the sets more than 2% worse than the landmark fit, the
    /// widest pair of halves of 16 photos):
    ///
    /// | photo weights | 2 / 3 / 4 / 8 / 16 | worst | mean | worse | halves |
    /// |---|---|---|---|---|---|
    /// | **off** | 0.78 / 0.72 / 0.70 / 0.66 / 0.62 | 1.17 / 0.99 / 1.22 / 1.01 / 1.08 | 0.694 | 4 | 0.70 mm |
    /// | lights at the weights (before) | 0.78 / 0.72 / 0.71 / 0.65 / 0.61 | 1.17 / 0.97 / 1.22 / 0.90 / 1.08 | 0.694 | 4 | 0.56 mm |
    /// | lights at full weight | 0.78 / 0.73 / 0.70 / 0.66 / 0.60 | 1.17 / 0.97 / 1.08 / 0.95 / 0.89 | 0.692 | 3 | 0.66 mm |
    ///
    /// The rendered photos disagree mildly, so their weights stay near 1 and the two ways of
    /// fitting the lights differ by about the refinement's own sensitivity (a change in the
    /// last bit of its input moves one refinement by several hundredths); three of the four
    /// sets worse than the landmark fit stay so (two of them have two photos, where the
    /// weights say nothing). On expressive photos (`photo_eval --expressions --seeds 2
    /// --counts 3,8`; neutral, smile, open jaw, 3 / 8 photos) 0.70 / 0.58, 0.79 / 0.74,
    /// 0.74 / 0.66 against the default's 0.69 / 0.57, 0.75 / 0.70, 0.74 / 0.68: the smiles
    /// lose. Left off.
    pub photo_weights: bool,
    /// [`Window::Lit`]: shade each photo over the normals of the face with that photo's
    /// expression (the landmark fit's), rather than over the identity's alone. On by default.
    /// Measured by `tools/photo_eval` (`--expressions --seeds 2 --counts 3,8 --methods
    /// "default,refine identity normals,landmarks only"`, `tools/results/expressions.md`; mean
    /// ratio to the mean face, each set scored against the neutral identity; the photos' mean
    /// expression measured by an earlier build in another run):
    ///
    /// | photos (3 / 8) | neutral | smile | open jaw | smile / neutral | open jaw / neutral |
    /// |---|---|---|---|---|---|
    /// | identity's normals | 0.71 / 0.62 | 0.85 / 0.84 | 0.73 / 0.69 | 1.19 / 1.33 | 1.04 / 1.11 |
    /// | **each photo's** | 0.69 / 0.61 | 0.76 / 0.71 | 0.75 / 0.70 | 1.11 / 1.15 | 1.09 / 1.17 |
    /// | the photos' mean expression | 0.70 / 0.62 | 0.80 / 0.77 | 0.76 / 0.70 | 1.18 / 1.24 | 1.10 / 1.14 |
    ///
    /// On the main evaluation without the displacement field (`--methods "default,refine
    /// identity normals,landmarks only"`, `tools/results/photos.md` at commit 634c043, 105 sets)
    /// both come to 0.806× the landmark fit on average,
    /// but the real scan's sets to 0.833× the mean face against 0.815× (its 8-photo sets 0.80 /
    /// 0.80 / 0.92× against 0.75 / 0.74 / 0.85×); 5 sets come out more than 2% worse than the
    /// landmark fit (4 with the identity's normals). On the scan's neutral photos the landmark
    /// fit finds expressions that are not there (a nose sneer of 0.3 in every photo of
    /// `lps-head/photos-8`), and their normals shade the nose wrongly. The expressions of the
    /// rendered subjects are the space's own blendshapes, which flatters this option; the scan
    /// is one face. Fading out samples an expression stretches (lips parted over the mouth's
    /// inside, an area ratio beyond 1.5) changed the open jaw's figures by 0.01 and was
    /// dropped. The visibility follows the same normals.
    pub expression_normals: bool,
    /// `τ_δ`, the prior deviation of an expression shift that the photos share, or `None` to
    /// hold each photo's expression at the landmark fit's. With it, the expressions the
    /// landmark fit gave the photos (those whose weight, averaged over the photos, reaches
    /// [`SHIFTED_EXPRESSION_MIN`]; at most [`SHIFTED_EXPRESSIONS_MAX`] of them, the strongest)
    /// move with the identity: each by a shift `δₗ` added to every photo's weight, costing
    /// `δₗ² / τ_δ²`, and held where a photo's weight would leave `[0, 1]`. To the pixels a shift
    /// the photos share is a change of shape like the identity's; the prior tells them apart (a
    /// smile's cheeks cost one blendshape's weight, many identity modes' otherwise), and the
    /// neutral identity is what the reconstruction shows. [`Refinement::expressions`] gives the
    /// shifted weights.
    ///
    /// Off by default: it helps expressive photos and hurts the real scan's neutral ones. Measured
    /// by `tools/photo_eval` (`--expressions --seeds 2 --counts 3,8 --methods "default,refine
    /// shift 0.25"`: error on the expressive photos over the error on the neutral ones, 3 / 8
    /// photos; and `--ict-subjects 0 --methods "default,refine shift 0.25,refine shift 0.5"`: the
    /// scan's 15 sets, mean ratio to the mean face):
    ///
    /// | `τ_δ` | smile | jaw open | the scan | its `photos-8` |
    /// |---|---|---|---|---|
    /// | **`None`** | 1.11 / 1.15 | 1.09 / 1.17 | 0.833 | 0.90 |
    /// | 0.25 | 1.10 / 1.09 | 1.08 / 1.15 | 0.855 | 0.93 |
    /// | 0.5 | | | 0.861 | 0.95 |
    ///
    /// On the scan the shared shift takes up identity shape (the scan's nose and cheeks) that
    /// the neutral output then drops; the rendered subjects' expressions are the space's own
    /// blendshapes, which flatters the option.
    ///
    /// Measured again with the displacement field ([`RefineOptions::field`], the default since;
    /// `photo_eval --expressions --expression-oracle --seeds 2 --counts 3,8 --methods
    /// "default,refine shift 1,landmarks only"` and `--methods "default,refine shift 0.25"`;
    /// `photo_eval --methods "refine shift 1,refine shift 0.25"`: the mean ratio to the mean
    /// face for 2 / 3 / 4 / 8 / 16 photos, the scan's 15 sets and its `photos-8`):
    ///
    /// | `τ_δ` | smile | jaw open | 2 / 3 / 4 / 8 / 16 | the scan | its `photos-8` |
    /// |---|---|---|---|---|---|
    /// | **`None`** | 1.12 / 1.22 | 1.09 / 1.19 | 0.78 / 0.72 / 0.70 / 0.66 / 0.62 | 0.834 | 0.83 |
    /// | 0.25 | 1.10 / 1.14 | 1.07 / 1.18 | 0.78 / 0.71 / 0.71 / 0.66 / 0.63 | 0.847 | 0.88 |
    /// | 1 | 1.09 / 1.11 | 1.09 / 1.17 | 0.81 / 0.72 / 0.72 / 0.65 / 0.63 | 0.875 | 0.91 |
    ///
    /// What the expressive photos lack is their expression: the landmark fit finds about
    /// half of a smile of 0.7 and of an open jaw of 0.35, and refined with every photo's true
    /// expression instead, the expressive photos give the neutral identity about as well as
    /// neutral photos do (`tools/results/expressions.md`, its oracle section). The shift moves
    /// a smile part of the way (0.23 to 0.44 on one subject's eight photos) and an open jaw
    /// hardly at all.
    ///
    /// It is the size of the expression's own blendshapes that is missing, not the small
    /// weights the fit spreads over the other 50 (`tools/results/expressions-modes.md`;
    /// expressive over neutral error, smile and jaw open, 3 / 8 photos): refined with only
    /// the expression's own blendshapes set to the truth and the others left at the fit's,
    /// 0.99 / 1.03 and 0.99 / 1.06, near the whole truth's 0.95 / 0.97 and 0.97 / 1.06; with
    /// the fit's weights on its own blendshapes and the others zeroed, 1.08 / 1.19 and
    /// 1.03 / 1.18, near the fit's own 1.09 / 1.23 and 1.04 / 1.16. Zeroing every expression
    /// of the neutral photos moves their ratio to the mean face from 0.72 / 0.54 to
    /// 0.70 / 0.53.
    ///
    /// Two other answers to the half-found expressions were measured and dropped (temporary
    /// switches, `photo_eval --expressions --seeds 2 --counts 3,8 --methods default`; neutral,
    /// smile, jaw open, 3 / 8 photos; then smile / neutral and jaw / neutral):
    ///
    /// | variant | neutral | smile | jaw open | smile / neutral | jaw / neutral |
    /// |---|---|---|---|---|---|
    /// | **the landmark fit's expressions** | 0.69 / 0.57 | 0.75 / 0.70 | 0.74 / 0.68 | 1.12 / 1.22 | 1.09 / 1.19 |
    /// | a sample counts `1 / (1 + (‖Gₛ eᵢ‖ / 1 unit)²)` in photo `i` | 0.75 / 0.59 | 0.86 / 0.81 | 0.80 / 0.66 | 1.19 / 1.37 | 1.10 / 1.13 |
    /// | every expression weight × 1.7 before the refinement (clamped to `[0, 1]`) | 0.72 / 0.60 | 0.77 / 0.70 | 0.82 / 0.78 | 1.11 / 1.19 | 1.16 / 1.31 |
    ///
    /// Trusting less the pixels an expression moves (the mouth and cheeks of a smile) takes
    /// away what the refinement gains there: the smile's pixels help the neutral face more
    /// than the expression's error in them hurts it. Scaled up before the refinement, the
    /// landmark fit's expressions leave the smile as it was and make the open jaw and the
    /// neutral photos (whose small weights grow too) worse: what the fit finds is not simply
    /// the true expression scaled down.
    pub expression_shift: Option<Real>,
    /// `τₑ`, the prior deviation of each photo's own expression shift, or `None` to hold each
    /// photo's expression at the landmark fit's (or at the shared shift's). With it, the
    /// expressions the landmark fit gave the photos (those whose weight, averaged over the
    /// photos, reaches [`SHIFTED_EXPRESSION_MIN`]; at most [`PHOTO_EXPRESSIONS_MAX`] of them,
    /// the strongest) move in each photo on its own: photo `i`'s weight `eᵢₗ` by `δᵢₗ`,
    /// costing `δᵢₗ² / τₑ²` and held in `[0, 1]`. The photos' pixels then tell each photo's
    /// expression by how the photo disagrees with the others, and the landmarks move with it.
    /// Each shift is a photo's unknown beside its camera's: the equations' per-photo blocks
    /// widen from 7 to up to 11.
    ///
    /// Off by default: where one photo's expression differs from the others' it finds it (a
    /// photo opening its jaw to 0.5 among neutral ones, started at 0.25, comes out at 0.505;
    /// the test `each_photos_own_shift_takes_up_the_expression_its_pixels_show`), but where
    /// the photos share their expression, as in the evaluation's expressive sets, the shifts
    /// move together and the pixels tell them from identity no better than the shared shift
    /// does. Measured by `tools/photo_eval` (`--expressions --seeds 2 --counts 3,8 --methods
    /// "default,refine photo expressions 0.25,refine photo expressions 0.5,refine photo
    /// expressions 1"`: the error from expressive photos over that from neutral ones, 3 / 8
    /// photos, and the neutral photos' ratio to the mean face; `--baseline
    /// tools/results/photos.md --methods "refine photo expressions 1,refine photo expressions
    /// 0.5"`: the 105 sets' mean ratio to the mean face, the sets more than 2% worse than the
    /// landmark fit, the real scan's 15 sets and its `photos-8` and `photos-3`):
    ///
    /// | `τₑ` | smile | jaw open | neutral | 105 sets | worse | the scan | `photos-8` / `-3` |
    /// |---|---|---|---|---|---|---|---|
    /// | **`None`** | 1.11 / 1.22 | 1.08 / 1.19 | 0.70 / 0.57 | 0.695 | 4 | 0.834 | 0.83 / 0.78 |
    /// | 0.25 | 1.12 / 1.21 | 1.05 / 1.17 | 0.70 / 0.58 | | | | |
    /// | 0.5 | 1.09 / 1.15 | 1.10 / 1.18 | 0.70 / 0.58 | 0.697 | 5 | 0.828 | 0.89 / 0.74 |
    /// | 1 | 1.09 / 1.09 | 1.06 / 1.18 | 0.70 / 0.58 | 0.707 | 2 | 0.827 | 0.92 / 0.73 |
    ///
    /// A smile comes back part of the way, as with the shared shift; an open jaw does not
    /// (dlib reads less of it than the points move, [`crate::face::ExpressionPrior`], and the
    /// landmarks hold each photo's shift as they hold the fit). The real scan's sets gain a
    /// little on average but its `photos-8` loses 0.06–0.09, and the 105 sets lose on average.
    ///
    /// That the landmarks hold the open jaw was measured with two temporary switches (the same
    /// expressive sets; smile and jaw open, 3 / 8 photos): with the landmarks blind to the
    /// shifts (they see each photo's expression at the fit's), `τₑ` 0.5 gives the open jaw
    /// 1.02 / 1.10 and 1 gives 1.07 / 1.11, but the smile 1.21 / 1.26 and 1.22 / 1.30; with the
    /// landmarks seeing the shifts at half their size, 1.15 / 1.21 and 1.08 / 1.12 (`τₑ` 0.5),
    /// 1.13 / 1.18 and 1.09 / 1.16 (1). The landmarks hold back an open jaw and keep a smile on
    /// course; which to trust for which expression is more than two rendered expressions can
    /// say.
    ///
    /// All of the above was measured with the rendered open mouths lip-coloured inside. With
    /// them dark, as in photos (`tools/results/expressions.md`), `τₑ = 1` gives smile 1.11 /
    /// 1.10 and jaw open 1.02 / 1.12 against the default's 1.15 / 1.20 and 1.06 / 1.19, and the
    /// shared shift of 1 gives 1.12 / 1.07 and 1.05 / 1.14.
    pub expression_photos: Option<Real>,
    /// How far the landmarks' weighted RMS may grow (canonical units) for the refinement to be
    /// kept. Unbounded by default: on `tools/photo_eval` it grew by up to 0.6 units on refinements
    /// that helped and on those that did not alike.
    pub landmark_slack: Real,
    /// Check the refinement on photos it did not see ([`Refinement::held_out`], the
    /// [module documentation](self)): the photos split into folds by yaw, each fold's photos
    /// held out while the others refine the face, and the held-out photos compared with the
    /// others' mean on that face and on the landmark fit's (its cameras refined by the same
    /// photos, the face held). Off by default: it turns down fewer harmful refinements than
    /// it turns down good ones. Measured by `tools/photo_eval` (`REFINE_DIAG=1 cargo run
    /// --release --example photo_eval -- --counts 3,4,8,16 --methods "refine held-out
    /// ungated"`, 8 iterations per level: 95 sets of 3–16 photos of the seven subjects, every
    /// refinement's figures;
    /// the mean ratio of the error to the landmark fit's with the refinement kept where the
    /// rule says, the sets more than 2% worse than the landmark fit, the worst):
    ///
    /// | kept when | mean | worse | worst |
    /// |---|---|---|---|
    /// | **the disagreement falls by 15%** (no check) | 0.823 | 4 | 1.10 |
    /// | and the photos left out agree no worse: folds at every level, the photos left out placed by their landmarks | 0.832 | 2 | 1.08 |
    /// | the same, folds at every level but the finest | 0.863 | 0 | 1.02 |
    /// | the same, the photos left out aligned by their pixels (this check) | 0.859 | 0 | 1.02 |
    /// | this check, the disagreement falling by 10% | 0.835 | 3 | 1.17 |
    ///
    /// It removes the few refinements that cost up to a tenth and many that gain far more: of
    /// the 73 refinements more than 2% better than the landmark fit, the photos left out
    /// agreed worse on 22 (by up to 2.4%); of the 19 more than 2% worse, they agreed no worse
    /// on 4. The photos left out differ from the others in their light, highlights and noise
    /// whatever the face, and the check's figure moves by about as much as the shape changes
    /// it. On the whole evaluation (107 sets, `--methods "default,refine no held-out,
    /// landmarks only"` with the check on in its third form above) the mean ratio to the mean
    /// face for 2 / 3 / 4 / 8 / 16 photos was 0.86 / 0.81 / 0.77 / 0.80 / 0.69 against 0.86 /
    /// 0.77 / 0.74 / 0.74 / 0.69 without it (an ICT identity's eight photos: 1.28 against
    /// 0.67, a refinement that halved the error turned down). The check doubles the refinement's
    /// time where it runs (eight photos of the scan: 94–170 ms without, 200–370 ms with).
    pub held_out: bool,
    /// The smallest relative fall of the held-out photos' disagreement for which the
    /// refinement is kept (with [`RefineOptions::held_out`]; sets of fewer than three photos
    /// have no folds and are judged by [`RefineOptions::min_gain`] alone).
    pub min_held_out_gain: Real,
    /// Hold the face at the fit's and refine only the cameras: the photos' disagreement on a
    /// given face with the cameras that suit it best (as the check on photos left out aligns
    /// its photos). Off by default. With it, [`Refinement::weights`] are the fit's and the
    /// disagreement's fall is the cameras' alone. `tools/photo_eval --from-truth` uses it to
    /// ask whether the photos agree better on the true face than on the refined one
    /// (`tools/results/from-truth.md`: with the default window they do not, on any of twelve
    /// sets of six ICT identities).
    pub hold_face: bool,
}

impl Default for RefineOptions {
    /// Three levels (eye distances of 20, 40 and 80 pixels, samples 8, 4 and 2 units apart),
    /// sixteen iterations each at most, `σ = 0.5`, `β = 0.03`, `ε = 4`, perspective cameras, the
    /// photos compared with the face lit ([`Window::Lit`]), a displacement field at the finest
    /// level ([`RefineOptions::field`], measured there; the table below without it), kept when
    /// the disagreement falls at all, in proportion up to a fall of 5% and whole from there (no
    /// check on photos left out, [`RefineOptions::held_out`]).
    ///
    /// The measure and its gate were chosen on the whole evaluation (`cargo run --release
    /// --example photo_eval -- --methods "default,landmarks only,refine lit,refine lit
    /// ungated"`, and `--methods "landmarks only,refine lit gate 0,refine lit ungated beta
    /// 0.1"`, the same 107 sets, 105 scored: the mean ratio of the error to the mean face's for
    /// 2 / 3 / 4 / 8 / 16 photos; to the landmark fit's, the sets more than 2% worse than it,
    /// the worst; the scan's two given sets; the largest distance between two halves of 16
    /// photos of one subject):
    ///
    /// | measure, kept | 2 | 3 | 4 | 8 | 16 | to the landmark fit | worse | worst | photos-8, photos-3 | halves |
    /// |---|---|---|---|---|---|---|---|---|---|---|
    /// | window in the image, from 10% to 20% (the former default) | 0.86 | 0.77 | 0.73 | 0.72 | 0.66 | 0.825 | 6 | 1.11 | 0.84, 0.79 | 0.78 mm |
    /// | lit, from 10% to 20% | 0.81 | 0.74 | 0.75 | 0.74 | 0.74 | 0.839 | 1 | 1.17 | 0.86, 0.84 | 1.07 mm |
    /// | lit, always | 0.79 | 0.71 | 0.71 | 0.69 | 0.70 | 0.800 | 5 | 1.17 | 0.88, 0.84 | 0.87 mm |
    /// | **lit, from 0% to 5%** | 0.79 | 0.73 | 0.72 | 0.70 | 0.71 | 0.811 | 1 | 1.17 | 0.88, 0.84 | 0.87 mm |
    /// | lit, `β = 0.1`, always | 0.71 | 0.64 | 0.62 | 0.69 | 0.68 | 0.746 | 11 | 1.23 | 1.02, 0.83 | 0.95 mm |
    ///
    /// The lit measure is better than the window in the image for up to eight photos and
    /// harms one set where the window harmed six, at a cost with sixteen photos (0.71 against
    /// 0.66), on the scan's two given sets and in the agreement of two halves; its
    /// disagreement falls less far than the window's (the shading it keeps is partly the
    /// light's), so its gate is lower. A larger `β` follows the photos further: better on the
    /// mean, harmful on eleven sets (the scan's eight given photos among them, 1.02× the mean
    /// face). The tables below were measured with the window in the image.
    ///
    /// Measured by `tools/photo_eval` (107 sets of 2–16 photo-realistic photos of the
    /// Lee Perry-Smith scan and six ICT-FaceKit identities wearing real skins, the whole photo
    /// path, the space cut to ICT's first 40 modes): mean ratio of the inner-face error to the
    /// mean face's for 2 / 3 / 4 / 8 / 16 photos (the landmark fit alone: 0.94 / 0.90 / 0.88 /
    /// 0.87 / 0.82), every refinement kept:
    ///
    /// | variant | 2 | 3 | 4 | 8 | 16 |
    /// |---|---|---|---|---|---|
    /// | `β = 0.1`, window in the image, orthographic cameras (κ = 0) | 0.97 | 0.84 | 0.95 | 0.88 | 0.89 |
    /// | `β = 0.1`, window in the image, perspective | 0.89 | 0.76 | 0.86 | 0.74 | 0.75 |
    /// | **`β = 0.03`**, window in the image, perspective | 0.90 | 0.77 | 0.81 | 0.71 | 0.69 |
    /// | `β = 0.03`, window on the surface | 0.89 | 0.83 | 0.82 | 0.75 | 0.72 |
    /// | `β = 0.1`, window on the surface | 0.89 | 0.83 | 0.88 | 0.82 | 0.83 |
    /// | `β = 0.3`, window on the surface | 0.94 | 0.92 | 1.00 | 0.97 | 0.98 |
    ///
    /// | `β = 0.03`, shading divided out ([`Window::Shaded`]) | 0.89 | 0.82 | 0.82 | 0.74 | 0.69 |
    ///
    /// (The image rows were measured before the cameras gained their principal point; a
    /// larger `β` follows the photos further and also their shading.) Kept only when the
    /// disagreement falls by `min_gain` (`β = 0.03`, 104 sets; mean ratio of the error to the
    /// landmark fit's, sets more than 2% worse than it, the worst):
    ///
    /// | `min_gain` | mean | worse | worst |
    /// |---|---|---|---|
    /// | 0 (always kept) | 0.87 | 32 | 1.45 |
    /// | 0.1 | 0.87 | 30 | 1.45 |
    /// | 0.15 | 0.86 | 23 | 1.28 |
    /// | **0.2** | 0.85 | 11 | 1.19 |
    /// | 0.25 | 0.88 | 4 | 1.16 |
    /// | 0.3 | 0.97 | 2 | 1.07 |
    ///
    /// With the shading divided out ([`Window::Shaded`], the same 105 sets; a later run):
    ///
    /// | `min_gain` | mean | worse | worst |
    /// |---|---|---|---|
    /// | 0 (always kept) | 0.90 | 17 | 1.20 |
    /// | 0.1 | 0.90 | 13 | 1.20 |
    /// | 0.15 | 0.91 | 11 | 1.20 |
    /// | 0.2 | 0.92 | 8 | 1.18 |
    /// | 0.25 | 0.93 | 5 | 1.18 |
    /// | 0.3 | 0.96 | 2 | 1.18 |
    ///
    /// Fewer faces made worse at every threshold, and less gained.
    ///
    /// The tables above were measured with the cameras' `κ` drawn toward 0 (orthographic).
    /// With [`TYPICAL_FOCAL`]'s prior (window in the image; 80 sets of 2–16 photos of all seven
    /// subjects, `REFINE_DIAG=1 cargo run --release --example photo_eval -- --ict-subjects 6
    /// --seeds 3 --counts 3,8,16 --methods "refine ungated"`; the same statistics; the
    /// landmark fit's disagreement the lower of its own orthographic cameras' and the
    /// refinement's starting ones'):
    ///
    /// | `min_gain` | mean | worse | worst |
    /// |---|---|---|---|
    /// | 0 (always kept) | 0.80 | 16 | 1.15 |
    /// | 0.1 | 0.80 | 12 | 1.15 |
    /// | 0.13 | 0.82 | 7 | 1.15 |
    /// | 0.15 | 0.84 | 4 | 1.10 |
    /// | 0.2 | 0.90 | 1 | 1.09 |
    /// | 0.25 | 0.94 | 1 | 1.09 |
    ///
    /// The prior's refinements fall less far in disagreement and are nearer the truth, so
    /// the threshold is lower than before. On the whole evaluation (107 sets, `--methods
    /// "default,landmarks only"`) it brought the mean ratio to the mean face for 2 / 3 / 4 /
    /// 8 / 16 photos from 0.87 / 0.80 / 0.78 / 0.76 / 0.71 (the former prior, threshold 0.2) to
    /// 0.87 / 0.78 / 0.76 / 0.75 / 0.70, and the mean ratio to the landmark fit from 0.861 (6
    /// sets more than 2% worse than it, the worst 1.18×) to 0.851 (6, 1.13×).
    ///
    /// Kept in proportion between two thresholds ([`RefineOptions::full_gain`]) rather than
    /// at one: on the whole evaluation (`cargo run --release --example photo_eval --
    /// --methods "default,landmarks only,refine ungated,refine step 15,refine soft 10-25,
    /// refine soft 5-20,refine soft 15-25"`, 105 sets scored; the mean ratio of the error to
    /// the mean face's for 2 / 3 / 4 / 8 / 16 photos; to the landmark fit's, the sets more
    /// than 2% worse than it, the worst; the scan's eight given photos; the largest distance
    /// between two halves of 16 photos of one subject):
    ///
    /// | kept | 2 | 3 | 4 | 8 | 16 | to the landmark fit | worse | worst | photos-8 | halves |
    /// |---|---|---|---|---|---|---|---|---|---|---|
    /// | always | 0.87 | 0.75 | 0.76 | 0.69 | 0.66 | 0.819 | 23 | 1.36 | 0.82 | 0.58 mm |
    /// | from a 15% fall (the former default) | 0.85 | 0.77 | 0.74 | 0.72 | 0.69 | 0.833 | 8 | 1.13 | 0.87 | 0.92 mm |
    /// | in proportion from 5% to 20% | 0.86 | 0.76 | 0.73 | 0.70 | 0.65 | 0.816 | 11 | 1.12 | 0.82 | 0.70 mm |
    /// | **in proportion from 10% to 20%** | 0.86 | 0.77 | 0.73 | 0.72 | 0.66 | 0.825 | 6 | 1.12 | 0.84 | 0.78 mm |
    /// | in proportion from 10% to 25% | 0.86 | 0.79 | 0.76 | 0.74 | 0.69 | 0.849 | 6 | 1.12 | 0.85 | 0.57 mm |
    /// | in proportion from 15% to 25% | 0.87 | 0.81 | 0.78 | 0.77 | 0.74 | 0.877 | 4 | 1.12 | 0.87 | 0.40 mm |
    ///
    /// The ramp from 10% to 20% is better than the former step on every figure but the two
    /// photos' mean (0.86 against 0.85): a refinement whose fall lies near the threshold is
    /// as likely to help as to harm, and half of it costs half as much where it harms. (The
    /// blended face with the refined cameras: eight photos of the scan agree on it about as
    /// well as on the refined face, 0.386 against 0.381, from 0.440 on the landmark fit.)
    ///
    /// No threshold keeps every
    /// set at least as good as the landmark fit with either: the refinement
    /// helps most where the landmarks left the face far from the truth and converges to about
    /// the same error wherever it starts, so on faces the landmarks already served well it
    /// can cost a little.
    fn default() -> Self {
        RefineOptions {
            levels: 3,
            eye_pixels: 80.0,
            spacing: 2.0,
            iterations: 16,
            sigma: 0.5,
            beta: 0.03,
            noise: 4.0,
            perspective: true,
            window: Window::Lit,
            window_eyes: NORMALISATION_EYES,
            field: true,
            field_levels: 1,
            field_bend: 3.0,
            field_sigma: 10.0,
            min_gain: 0.0,
            full_gain: 0.05,
            photo_weights: false,
            expression_normals: true,
            expression_shift: None,
            expression_photos: None,
            landmark_slack: Real::INFINITY,
            held_out: false,
            min_held_out_gain: 0.0,
            hold_face: false,
        }
    }
}

/// How the photos' intensities are made comparable: where the local normalisation takes its
/// window, or none with the face lit instead (see the [module documentation](self)).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Window {
    /// In each photo's image, [`NORMALISATION_EYES`] of that photo's eye distances: each
    /// photo's crop is normalised once per level.
    Image,
    /// On the surface, [`NORMALISATION_EYES`] eye distances about each sample, over the
    /// samples the photo sees: the same part of the face in every photo.
    Surface,
    /// As [`Window::Surface`], of the intensities with each photo's shading divided out: a
    /// first-order spherical-harmonic lighting per photo (ambient plus one direction, four
    /// coefficients) over the mean face's normals, fitted with an albedo per sample shared by
    /// the photos, refitted wherever the cost is taken. A light that moves between photos
    /// brightens one side of the nose in one photo and the other in the next, faster than
    /// any window can follow; the lighting model removes it where it arises. Measured against
    /// the default in [`RefineOptions::default`]: fewer faces made worse than the landmark
    /// fit, but less gained on the others.
    Shaded,
    /// Analysis by synthesis: each photo is compared with the face *lit*, not with a window
    /// of itself. The photos' intensities are made linear (the sRGB curve undone), each
    /// photo's first-order spherical-harmonic lighting is fitted over the **current shape's
    /// own normals** in that photo (the identity surface with the photo's expression from the
    /// landmark fit; the albedo per sample shared by the photos, as [`Window::Shaded`] fits
    /// it), divided out, and what is left is scaled by a gain and bias per photo (its
    /// mean and deviation over the samples it sees). The shading stays in the measure: the
    /// brightness falling off across a nose's side depends on the nose's shape, and the
    /// Gauss-Newton steps follow it through the normals' derivatives in the identity weights
    /// (the identity surface's, shared by the photos; the field's bending of the normals is
    /// left out). The photos' visibility follows the same normals.
    /// Chosen after `tools/photo_eval --from-truth` found that under every window the true
    /// face left the photos disagreeing more than the refined one: a window of a photo's own
    /// intensities removes the shading that says where the surface turns, and keeps the
    /// light's moving edge.
    Lit,
}

/// One photo as [`FaceSpace::refine_photos`] takes it.
#[derive(Debug, Clone, Copy)]
pub struct RefineView<'a> {
    /// The grey image (`y` down).
    pub image: &'a GreyImage,
    /// Its 40 points, `y` up ([`crate::align::PhotoPoints::y_up`]).
    pub points: &'a [Point2<Real>],
}

/// A photo's camera after refinement, a pinhole camera with its principal point at the
/// image's centre `c`: `x = c + (o − c + s · P R X) / (1 − κ (R X)_z)`, `y` up, in the
/// photo's pixels. `o` is where the structure's origin projects, `s` the pixels per canonical
/// unit there, `κ` the inverse of the origin's distance from the camera; with `κ = 0` it is
/// the landmark fit's scaled orthographic camera `x = o + s · P R X`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefinedCamera {
    /// `R`.
    pub rotation: Rotation3<Real>,
    /// `s`, pixels per canonical unit.
    pub scale: Real,
    /// `o`, pixels (`y` up).
    pub offset: Vector2<Real>,
    /// `κ`, per canonical unit: the inverse of the camera's distance (0: orthographic).
    pub perspective: Real,
    /// `c`, the principal point (the image's centre), pixels (`y` up); fixed.
    pub centre: Vector2<Real>,
}

/// A camera's projection of a point, linearised.
struct Projected {
    /// `q = R X`.
    q: Vector3<Real>,
    /// The image point (`y` up).
    p: Point2<Real>,
    /// `∂p/∂q`.
    dq: Matrix2x3<Real>,
    /// `∂p/∂(log s, oₓ, o_y, κ)`.
    dcamera: nalgebra::Matrix2x4<Real>,
}

impl Projected {
    /// `∂pₐ/∂(δ, log s, o, κ)` for row `a`: the rotation's part through `∂q/∂δ = −[q]×`.
    fn camera_row(&self, a: usize) -> [Real; CAMERA] {
        let dqa: Vector3<Real> = self.dq.row(a).transpose();
        let rotation = self.q.cross(&dqa);
        let c = self.dcamera.row(a);
        [rotation.x, rotation.y, rotation.z, c[0], c[1], c[2], c[3]]
    }
}

impl RefinedCamera {
    /// The landmark fit's scaled orthographic camera (`κ = 0`) for a photo of `width × height`
    /// pixels: `pose` and `offset` as [`PhotoSpaceFit::poses`] gives them (`y` up).
    pub fn orthographic(
        pose: &crate::depth::Pose,
        offset: Point2<Real>,
        (width, height): (u32, u32),
    ) -> Self {
        RefinedCamera {
            rotation: pose.rotation,
            scale: pose.scale,
            offset: offset.coords,
            perspective: 0.0,
            centre: Vector2::new((Real::from(width) - 1.0) / 2.0, -(Real::from(height) - 1.0) / 2.0),
        }
    }

    /// A pinhole camera of the photo-realistic renderer ([`crate::render::Camera`]) as a
    /// refined camera: `R = diag(1, −1, −1) R_cam`, `κ = 1/t_z`, `s = f/t_z`, the principal
    /// point kept. `None` when the world's origin is not in front of the camera.
    pub fn from_pinhole(camera: &crate::render::Camera) -> Option<Self> {
        let t = camera.translation;
        if t.z.is_nan() || t.z <= 0.0 {
            return None;
        }
        let flip = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_diagonal(&Vector3::new(
            1.0, -1.0, -1.0,
        )));
        let scale = camera.focal / t.z;
        Some(RefinedCamera {
            rotation: flip * camera.rotation,
            scale,
            offset: Vector2::new(camera.centre.x + scale * t.x, -camera.centre.y - scale * t.y),
            perspective: 1.0 / t.z,
            centre: Vector2::new(camera.centre.x, -camera.centre.y),
        })
    }

    /// How the camera sees the surface point `x` with unit normal `normal` (canonical frame):
    /// where in its photo, how deep, the cosine between the normal and the direction to the
    /// camera, and the pixels per canonical unit there ([`Look`]); `None` behind the camera
    /// (or too near it).
    pub fn look(&self, x: &Point3<Real>, normal: &Vector3<Real>) -> Option<Look> {
        let q = self.rotation * x.coords;
        let den = self.depth_factor(&q)?;
        let p = self.centre + (self.offset - self.centre + Vector2::new(q.x, q.y) * self.scale) / den;
        Some(Look {
            pixel: Point2::new(p.x, -p.y),
            key: q.z / den,
            cos: (self.rotation * normal).dot(&self.towards_from(&q)),
            resolution: self.scale / den,
        })
    }

    /// Where the camera sees `x` in its photo (pixels, `y` down: image rows), or `None`
    /// behind the camera: [`RefinedCamera::look`]'s pixel.
    pub fn pixel(&self, x: &Point3<Real>) -> Option<Point2<Real>> {
        self.look(x, &Vector3::z()).map(|look| look.pixel)
    }

    /// The pixels per canonical unit at `x` (the scale magnified by the perspective), or
    /// `None` behind the camera.
    pub fn resolution(&self, x: &Point3<Real>) -> Option<Real> {
        Some(self.scale / self.depth_factor(&(self.rotation * x.coords))?)
    }

    /// `1 − κ q_z` for `q = R X`: the point's distance from the camera over the origin's;
    /// `None` behind the camera or too near it.
    fn depth_factor(&self, q: &Vector3<Real>) -> Option<Real> {
        let den = 1.0 - self.perspective * q.z;
        (den >= 0.2).then_some(den)
    }

    /// The unit vector toward the camera from `q = R X`, in the camera's frame (the camera
    /// sits at `q = (0, 0, 1/κ)`, or at infinity along `+z` when `κ = 0`).
    fn towards_from(&self, q: &Vector3<Real>) -> Vector3<Real> {
        Vector3::new(
            -self.perspective * q.x,
            -self.perspective * q.y,
            1.0 - self.perspective * q.z,
        )
        .normalize()
    }

    /// Where the camera sees `x`, linearised; `None` behind the camera (or too near it).
    fn project(&self, x: &Point3<Real>) -> Option<Projected> {
        let q = self.rotation * x.coords;
        let den = self.depth_factor(&q)?;
        let m = self.offset - self.centre + Vector2::new(q.x, q.y) * self.scale;
        let p = Point2::from(self.centre + m / den);
        let (f, g) = (self.scale / den, self.perspective / (den * den));
        let dq = Matrix2x3::new(f, 0.0, g * m.x, 0.0, f, g * m.y);
        let (sx, sy) = (f * q.x, f * q.y);
        let dcamera = nalgebra::Matrix2x4::new(
            sx,
            1.0 / den,
            0.0,
            m.x * q.z / (den * den),
            sy,
            0.0,
            1.0 / den,
            m.y * q.z / (den * den),
        );
        Some(Projected { q, p, dq, dcamera })
    }

    /// The camera moved by a step `[δ (3), log-scale, offset (2), κ]`.
    fn moved(&self, step: &[Real]) -> Self {
        RefinedCamera {
            rotation: Rotation3::new(Vector3::new(step[0], step[1], step[2])) * self.rotation,
            scale: self.scale * step[3].exp(),
            offset: self.offset + Vector2::new(step[4], step[5]),
            perspective: (self.perspective + step[6]).max(0.0),
            centre: self.centre,
        }
    }
}

/// How a camera sees a point of a surface ([`RefinedCamera::look`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Look {
    /// Where, in the photo's pixels with `y` down (image rows).
    pub pixel: Point2<Real>,
    /// The depth key `(R X)_z / (1 − κ (R X)_z)`: larger toward the camera, and affine in the
    /// image (so that it may be interpolated linearly over a projected triangle).
    pub key: Real,
    /// The cosine between the surface's normal and the direction to the camera.
    pub cos: Real,
    /// Pixels per canonical unit there.
    pub resolution: Real,
}

/// Unknowns per photo: rotation (3), log-scale, offset (2), perspective.
const CAMERA: usize = 7;

/// The most expressions each photo shifts on its own ([`RefineOptions::expression_photos`]).
pub const PHOTO_EXPRESSIONS_MAX: usize = 4;

/// A photo's block of unknowns at its widest: its camera's and its own expression shifts.
const PHOTO_MAX: usize = CAMERA + PHOTO_EXPRESSIONS_MAX;

/// The expressions [`RefineOptions::expression_shift`] (or
/// [`RefineOptions::expression_photos`]) moves: those whose weight, averaged over the photos,
/// reaches [`SHIFTED_EXPRESSION_MIN`], the strongest `max` at most, in the modes' order.
fn shifted_expressions(expressions: &[Vec<Real>], max: usize) -> Vec<usize> {
    let n = expressions.len().max(1) as Real;
    let modes = expressions.first().map_or(0, Vec::len);
    let mut strong: Vec<(usize, Real)> = (0..modes)
        .map(|l| (l, expressions.iter().map(|e| e[l]).sum::<Real>() / n))
        .filter(|&(_, mean)| mean >= SHIFTED_EXPRESSION_MIN)
        .collect();
    strong.sort_by(|a, b| b.1.total_cmp(&a.1));
    strong.truncate(max);
    let mut chosen: Vec<usize> = strong.into_iter().map(|(l, _)| l).collect();
    chosen.sort_unstable();
    chosen
}

/// The smallest weight, averaged over the photos, of an expression that
/// [`RefineOptions::expression_shift`] moves.
pub const SHIFTED_EXPRESSION_MIN: Real = 0.05;

/// The most expressions [`RefineOptions::expression_shift`] moves (each costs the
/// refinement's equations what an identity mode does).
pub const SHIFTED_EXPRESSIONS_MAX: usize = 12;

/// What [`FaceSpace::refine_photos`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// The identity weights: the refined ones when [`Refinement::accepted`], else the landmark
    /// fit's.
    pub weights: Vec<Real>,
    /// The displacement of every control point of the space's member with
    /// [`Refinement::weights`] (row-major; along `z`), when [`RefineOptions::field`] asked for
    /// one and the refinement was kept; empty otherwise.
    pub displacement: Vec<Vector3<Real>>,
    /// The refined cameras, one per photo (the landmark fit's when not accepted).
    pub cameras: Vec<RefinedCamera>,
    /// Each photo's expression weights: the landmark fit's, shifted where
    /// [`RefineOptions::expression_shift`] moved them and the refinement was kept.
    pub expressions: Vec<Vec<Real>>,
    /// The photos' disagreement (weighted RMS of the normalised intensities about each
    /// sample's mean) on the landmark fit's face and on the refined one, finest level.
    pub disagreement: (Real, Real),
    /// The landmarks' weighted RMS (canonical units) before and after.
    pub landmark_rms: (Real, Real),
    /// The photos' disagreement over the face before and after, finest level
    /// (`consistency.png`).
    pub map: ConsistencyMap,
    /// Per photo: the fraction of the face's samples it sees, finest level.
    pub coverage: Vec<Real>,
    /// Samples at the finest level, and those seen by two photos or more.
    pub samples: (usize, usize),
    /// Gauss-Newton iterations run over all levels.
    pub iterations: usize,
    /// With [`RefineOptions::held_out`] and three photos or more: the held-out photos'
    /// disagreement with the others' mean (weighted RMS of the normalised intensities over
    /// every fold's held-out photos) on the landmark fit's face and on the face the other
    /// photos refined.
    pub held_out: Option<(Real, Real)>,
    /// Whether the refinement was kept (whole or in part).
    pub accepted: bool,
    /// How much of the way from the landmark fit to the refined face was kept: 1 when kept
    /// whole, 0 when turned down, between when the disagreement fell by less than
    /// [`RefineOptions::full_gain`]. [`Refinement::weights`], [`Refinement::displacement`],
    /// [`Refinement::cameras`] and the map's `after` are the kept face's.
    pub share: Real,
    /// Why, in words.
    pub note: String,
}

impl Refinement {
    /// The largest and the RMS length of [`Refinement::displacement`] over the control points
    /// (canonical units); `None` without a displacement.
    pub fn displacement_size(&self) -> Option<(Real, Real)> {
        if self.displacement.is_empty() {
            return None;
        }
        let max = self.displacement.iter().map(|d| d.norm()).fold(0.0, Real::max);
        let squares: Real = self.displacement.iter().map(|d| d.norm_squared()).sum();
        Some((max, (squares / self.displacement.len() as Real).sqrt()))
    }
}

/// Where on the face the photos agree: per sample of the finest level, laid on the frontal
/// sampling grid, the weighted RMS of the photos' normalised intensities about their mean.
#[derive(Debug, Clone, PartialEq)]
pub struct ConsistencyMap {
    /// Columns (along `x`).
    pub width: usize,
    /// Rows (along `y`, from the bottom).
    pub height: usize,
    /// On the landmark fit's face, row-major from the bottom; NaN where fewer than two photos
    /// see the face (or outside it).
    pub before: Vec<Real>,
    /// The same on the refined face.
    pub after: Vec<Real>,
}

/// A photo at one level: the face's crop, resampled and lightly blurred, with its gradient.
struct LevelImage {
    width: usize,
    height: usize,
    /// The crop's pixel `(c, r)` is the photo's pixel `origin + (c, r) / factor` (`y` down).
    origin: Vector2<Real>,
    factor: Real,
    /// Per crop pixel, row-major: the intensity and its central differences along `x` and
    /// `y` (crop pixels), with a pad. Interleaved so that a bilinear lookup of all three
    /// reads each of its four corners from one place ([`LevelImage::sample`]).
    texels: Vec<[f32; 4]>,
}

impl LevelImage {
    /// The photo's crop about `box_` (`[x0, y0, x1, y1]` in its pixels, `y` down) at `factor`
    /// crop pixels per photo pixel (at most 1), normalised over `window` crop pixels (a
    /// Gaussian deviation) when one is given ([`Window::Image`]), its intensities made linear
    /// (the sRGB curve undone) when `linear` ([`Window::Lit`]).
    fn new(image: &GreyImage, box_: [Real; 4], factor: Real, window: Option<Real>, linear: bool) -> Self {
        let origin = Vector2::new(box_[0], box_[1]);
        let width = (((box_[2] - box_[0]) * factor).ceil() as usize).max(8);
        let height = (((box_[3] - box_[1]) * factor).ceil() as usize).max(8);
        let mut crop = area_sample(image, (origin, factor), (width, height));
        if linear {
            crop.iter_mut().for_each(|v| *v = srgb_to_linear(*v));
        }
        let crop = blur(&crop, width, height, 0.7);
        let values = match window {
            None => crop,
            Some(window) => {
                let mean = blur(&crop, width, height, window);
                let centred: Vec<f32> = crop.iter().zip(&mean).map(|(v, m)| v - m).collect();
                let squares: Vec<f32> = centred.iter().map(|v| v * v).collect();
                let variance = blur(&squares, width, height, window);
                let floor = (DEVIATION_FLOOR * DEVIATION_FLOOR) as f32;
                centred
                    .iter()
                    .zip(&variance)
                    .map(|(v, s)| v / (s + floor).sqrt())
                    .collect()
            }
        };
        let (gx, gy) = crate::align::central_differences(&values, width, height);
        let texels = values
            .iter()
            .zip(gx.iter().zip(&gy))
            .map(|(&v, (&gx, &gy))| [v, gx, gy, 0.0])
            .collect();
        LevelImage {
            width,
            height,
            origin,
            factor,
            texels,
        }
    }

    /// Whether a crop place lies inside the crop.
    fn contains(&self, at: &Vector2<Real>) -> bool {
        at.x >= 0.0 && at.y >= 0.0 && at.x <= (self.width - 1) as Real && at.y <= (self.height - 1) as Real
    }

    /// The crop's coordinates of a photo point given `y` up.
    fn crop_of(&self, p: &Point2<Real>) -> Vector2<Real> {
        Vector2::new(
            (p.x - self.origin.x) * self.factor,
            (-p.y - self.origin.y) * self.factor,
        )
    }

    /// The intensity and its gradient in the photo's `y`-up pixels at a crop place;
    /// `None` outside the crop.
    ///
    /// A place outside the crop reads its nearest border pixel with no gradient: a sample that
    /// the visibility test let in ([`LevelImage::contains`]) keeps a residual wherever a step
    /// moves it, so that leaving the crop does not lower the cost.
    fn sample(&self, at: &Vector2<Real>) -> Option<(Real, Vector2<Real>)> {
        if !(at.x.is_finite() && at.y.is_finite()) {
            return None;
        }
        let inside = self.contains(at);
        let x = at.x.clamp(0.0, (self.width - 1) as Real);
        let y = at.y.clamp(0.0, (self.height - 1) as Real);
        // Truncation is the floor here (x, y ≥ 0), and no call into libm on baseline x86-64.
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = (x - x0 as Real, y - y0 as Real);
        let w = self.width;
        let corners = [
            &self.texels[y0 * w + x0],
            &self.texels[y0 * w + x1],
            &self.texels[y1 * w + x0],
            &self.texels[y1 * w + x1],
        ];
        // Channel `k` bilinearly: along `x` on the two rows, then along `y`.
        let at = |k: usize| {
            let top = Real::from(corners[0][k]) * (1.0 - fx) + Real::from(corners[1][k]) * fx;
            let bottom = Real::from(corners[2][k]) * (1.0 - fx) + Real::from(corners[3][k]) * fx;
            top * (1.0 - fy) + bottom * fy
        };
        // d(crop)/d(photo, y up) = factor · diag(1, −1).
        let g = if inside {
            Vector2::new(at(1) * self.factor, -at(2) * self.factor)
        } else {
            Vector2::zeros()
        };
        Some((at(0), g))
    }
}
/// The sRGB transfer curve undone: an encoded intensity in `[0, 1]` to linear light.
fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// One axis of [`area_sample`]'s samples: for each of `count` crop pixels, `k` bilinear taps
/// `(first pixel, second pixel, fraction toward the second)` at
/// `origin + (c + (b + ½)/k − ½)/factor`, clamped to `[0, last]` (as [`GreyImage::sample`]).
fn area_taps(origin: Real, factor: Real, k: usize, count: usize, last: usize) -> Vec<(usize, usize, f32)> {
    (0..count * k)
        .map(|t| {
            let (c, b) = (t / k, t % k);
            let x = origin + (c as Real + (b as Real + 0.5) / k as Real - 0.5) / factor;
            let x = x.clamp(0.0, last as Real);
            // Truncation is the floor here (x ≥ 0).
            let x0 = x as usize;
            (x0, (x0 + 1).min(last), (x - x0 as Real) as f32)
        })
        .collect()
}

/// The `width × height` crop of `image` whose pixel `(c, r)` is the photo's pixel
/// `origin + (c, r)/factor`, by area sampling: each crop pixel is the mean of `k × k` bilinear
/// samples over its footprint, `k = ⌈1/factor⌉`. The bilinear weights are separable, so the
/// samples along `x` are summed once per photo row (`across`), then weighed along `y`: the
/// same mean as the `k²` samples one by one (to rounding), with about `2k²` multiplications
/// per crop pixel instead of `k²` whole samples.
fn area_sample(
    image: &GreyImage,
    (origin, factor): (Vector2<Real>, Real),
    (width, height): (usize, usize),
) -> Vec<f32> {
    let k = (1.0 / factor).ceil().max(1.0) as usize;
    let values = image.data();
    let (w, h) = (image.width(), image.height());
    let xs = area_taps(origin.x, factor, k, width, w - 1);
    let ys = area_taps(origin.y, factor, k, height, h - 1);
    // The photo rows the samples read.
    let first = ys.iter().map(|t| t.0).min().unwrap_or(0);
    let last = ys.iter().map(|t| t.1).max().unwrap_or(0);
    let mut across = vec![0.0f32; (last - first + 1) * width];
    across.par_chunks_mut(width).enumerate().for_each(|(i, out)| {
        let row = &values[(first + i) * w..(first + i + 1) * w];
        for (o, taps) in out.iter_mut().zip(xs.chunks(k)) {
            *o = taps
                .iter()
                .map(|&(x0, x1, f)| row[x0] * (1.0 - f) + row[x1] * f)
                .sum();
        }
    });
    let scale = 1.0 / (k * k) as f32;
    let mut crop = vec![0.0f32; width * height];
    crop.par_chunks_mut(width)
        .zip(ys.par_chunks(k))
        .for_each(|(out, taps)| {
            for &(y0, y1, f) in taps {
                let (top, bottom) = (&across[(y0 - first) * width..], &across[(y1 - first) * width..]);
                for (c, o) in out.iter_mut().enumerate() {
                    *o += top[c] * (1.0 - f) + bottom[c] * f;
                }
            }
            out.iter_mut().for_each(|o| *o *= scale);
        });
    crop
}

/// A separable Gaussian blur of deviation `sigma` pixels (borders clamped).
///
/// Both passes run along rows with the taps outermost, so that the inner loops are plain
/// multiply-adds over contiguous runs the compiler vectorises: the row pass over a copy of
/// the row padded with its border values, the column pass over whole rows.
fn blur(values: &[f32], width: usize, height: usize, sigma: Real) -> Vec<f32> {
    let radius = (3.0 * sigma).ceil() as usize;
    let kernel: Vec<f32> = (0..=2 * radius)
        .map(|t| {
            let d = t as Real - radius as Real;
            (-(d * d) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let mut across = vec![0.0f32; width * height];
    across
        .par_chunks_mut(width)
        .zip(values.par_chunks(width))
        .for_each(|(out, row)| {
            let mut padded = Vec::with_capacity(width + 2 * radius);
            padded.extend(std::iter::repeat_n(row[0], radius));
            padded.extend_from_slice(row);
            padded.extend(std::iter::repeat_n(row[width - 1], radius));
            for (t, &k) in kernel.iter().enumerate() {
                for (o, v) in out.iter_mut().zip(&padded[t..t + width]) {
                    *o += k * v;
                }
            }
        });
    let mut out = vec![0.0f32; width * height];
    out.par_chunks_mut(width).enumerate().for_each(|(r, out)| {
        for (t, &k) in kernel.iter().enumerate() {
            let source = (r + t).saturating_sub(radius).min(height - 1);
            for (o, v) in out.iter_mut().zip(&across[source * width..(source + 1) * width]) {
                *o += k * v;
            }
        }
    });
    out
}

/// The surface samples of one level: the identity space's points and modes there, each
/// photo's expression displacement, and the mean face's normals.
struct Samples {
    base: Vec<Point3<Real>>,
    /// `modes[s][k]`.
    modes: Vec<Vec<Vector3<Real>>>,
    /// `expression[i][s]`.
    expression: Vec<Vec<Vector3<Real>>>,
    /// `photo_modes[s][l]`: each expression the photos shift on their own
    /// ([`Problem::photo_shifted`]) at the sample.
    photo_modes: Vec<Vec<Vector3<Real>>>,
    normals: Vec<Vector3<Real>>,
    /// Each sample's place on the sampling grid (columns along `x`, rows along `y`, up).
    cells: Vec<(i64, i64)>,
    /// Each sample's neighbours on the surface for the local normalisation, with their
    /// Gaussian weights (itself included).
    neighbours: Vec<Vec<(usize, Real)>>,
    /// Each sample's basis functions: control point index and value.
    basis: Vec<Vec<(usize, Real)>>,
    /// The samples' spacing, canonical units.
    spacing: Real,
    /// Per sample, the base surface's partial derivatives `(F_u, F_v)` and, per mode, its
    /// displacement's `(D_u, D_v)`: what the shape's own normals are made of ([`Window::Lit`];
    /// empty for the other windows).
    partials: Vec<(Tangents, Vec<Tangents>)>,
    /// Per photo and sample, its expression displacement's `(E_u, E_v)` (`[i][s]`; empty
    /// without partials or expressions).
    expression_partials: Vec<Vec<Tangents>>,
    /// Per sample, the partial derivatives of [`Samples::photo_modes`] (`[s][l]`; empty
    /// without expression partials).
    photo_partials: Vec<Vec<Tangents>>,
}

/// Which partial derivatives [`Samples::new`] keeps: none (the windows), the identity
/// space's ([`Window::Lit`]), or also each photo's expression's
/// ([`RefineOptions::expression_normals`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Partials {
    None,
    Identity,
    WithExpressions,
}

/// A surface's (or a mode's) partial derivatives `(∂/∂u, ∂/∂v)` at a sample.
type Tangents = [Vector3<Real>; 2];

impl Samples {
    /// `expressions[i]`: photo `i`'s expression as a displacement of every control point;
    /// `shifted`: further modes after the identity's, as displacements of every control point
    /// (the expressions [`RefineOptions::expression_shift`] moves); `photo_shifted`: the
    /// expressions each photo shifts on its own ([`RefineOptions::expression_photos`]), as
    /// displacements of every control point; `window_eyes` the local
    /// normalisation's window on the surface ([`neighbours`]); `partials` which of the
    /// surfaces' partial derivatives to keep ([`Samples::partials`],
    /// [`Samples::expression_partials`]).
    #[allow(clippy::too_many_arguments)]
    fn new(
        space: &FaceSpace,
        reference: &ReferenceFace,
        expressions: &[Vec<Vector3<Real>>],
        shifted: &[&[Vector3<Real>]],
        photo_shifted: &[&[Vector3<Real>]],
        spacing: Real,
        window_eyes: Real,
        partials: Partials,
    ) -> Result<Self, FaceError> {
        let frame = reference.frame();
        let mut params = Vec::new();
        let mut cells = Vec::new();
        let (x0, x1) = (frame.x[0].min(frame.x[1]), frame.x[0].max(frame.x[1]));
        let (y0, y1) = (frame.y[0].min(frame.y[1]), frame.y[0].max(frame.y[1]));
        let mut y = y0 + spacing / 2.0;
        while y < y1 {
            let mut x = x0 + spacing / 2.0;
            while x < x1 {
                let q = frame.parameters(x, y);
                if (0.0..=1.0).contains(&q.x)
                    && (0.0..=1.0).contains(&q.y)
                    && reference.in_face_region(q.x, q.y)
                {
                    params.push([q.x, q.y]);
                    cells.push((((x - x0) / spacing) as i64, ((y - y0) / spacing) as i64));
                }
                x += spacing;
            }
            y += spacing;
        }
        let surfaces = space.surfaces();
        let sampled = surfaces.sample(&params)?;
        let matrix = surfaces.base().basis_matrix(&params)?;
        let basis: Vec<Vec<(usize, Real)>> = (0..params.len())
            .map(|s| {
                let (cols, vals) = matrix.row(s);
                cols.iter().copied().zip(vals.iter().copied()).collect()
            })
            .collect();
        let at = |row: &[(usize, Real)], grid: &[Vector3<Real>]| -> Vector3<Real> {
            row.iter().map(|&(c, b)| grid[c] * b).sum()
        };
        let modes = (0..params.len())
            .map(|s| {
                let identity = sampled.modes.iter().map(|m| m[s]);
                identity
                    .chain(shifted.iter().map(|grid| at(&basis[s], grid)))
                    .collect()
            })
            .collect();
        let expression = expressions
            .iter()
            .map(|grid| basis.iter().map(|row| at(row, grid)).collect())
            .collect();
        let photo_modes = basis
            .iter()
            .map(|row| photo_shifted.iter().map(|grid| at(row, grid)).collect())
            .collect();
        let base_surface = surfaces.base();
        let normals = params
            .iter()
            .map(|&[u, v]| {
                Ok(base_surface
                    .normal(u, v)?
                    .map(|n| n.into_inner())
                    .unwrap_or_else(Vector3::z))
            })
            .collect::<Result<Vec<_>, FaceError>>()?;
        // The grid's normals point toward the viewer of the canonical frame (+z).
        let normals = normals
            .into_iter()
            .map(|n: Vector3<Real>| if n.z < 0.0 { -n } else { n })
            .collect();
        let with_expressions = partials == Partials::WithExpressions;
        let (partials, expression_partials, photo_partials) = if partials != Partials::None {
            // One evaluation of the basis's derivatives per sample serves the base, every mode
            // and every photo's expression.
            let (du, dv) = (
                base_surface.derivative_basis_matrix(&params, (1, 0))?,
                base_surface.derivative_basis_matrix(&params, (0, 1))?,
            );
            let apply = |s: usize, grid: &dyn Fn(usize) -> Vector3<Real>| -> Tangents {
                let ((cu, wu), (cv, wv)) = (du.row(s), dv.row(s));
                [
                    cu.iter().zip(wu).map(|(&c, &w)| grid(c) * w).sum(),
                    cv.iter().zip(wv).map(|(&c, &w)| grid(c) * w).sum(),
                ]
            };
            let base_points = base_surface.control_points();
            let modes = surfaces.modes();
            let partials = (0..params.len())
                .into_par_iter()
                .map(|s| {
                    let base = apply(s, &|c| base_points[c].coords);
                    let mode_tangents = modes
                        .iter()
                        .map(Vec::as_slice)
                        .chain(shifted.iter().copied())
                        .map(|m| apply(s, &|c| m[c]))
                        .collect();
                    (base, mode_tangents)
                })
                .collect();
            let expression_partials = expressions
                .par_iter()
                .filter(|_| with_expressions)
                .map(|grid| (0..params.len()).map(|s| apply(s, &|c| grid[c])).collect())
                .collect();
            let photo_partials = (0..params.len())
                .into_par_iter()
                .filter(|_| with_expressions)
                .map(|s| photo_shifted.iter().map(|grid| apply(s, &|c| grid[c])).collect())
                .collect();
            (partials, expression_partials, photo_partials)
        } else {
            (Vec::new(), Vec::new(), Vec::new())
        };
        Ok(Samples {
            partials,
            expression_partials,
            photo_partials,
            photo_modes,
            base: sampled.base,
            modes,
            expression,
            normals,
            neighbours: neighbours(&cells, spacing, window_eyes),
            cells,
            basis,
            spacing,
        })
    }

    fn len(&self) -> usize {
        self.base.len()
    }

    /// Sample `s` of photo `i`, the samples [`Samples::placed`] at `state`.
    fn point(&self, placed: &[Placed], state: &State, s: usize, i: usize) -> Point3<Real> {
        let (identity, lift) = placed[s];
        let mut p = identity;
        if let Some(e) = self.expression.get(i) {
            p += e[s];
        }
        for (d, shift) in self.photo_modes[s]
            .iter()
            .zip(state.shifts.get(i).into_iter().flatten())
        {
            p += d * *shift;
        }
        p.z += lift;
        p
    }

    /// Every sample's identity point at `state` (the base and the weighted modes) and the
    /// field's lift along `z`: what [`Samples::point`] adds each photo's expression to, formed
    /// once per state rather than once per photo.
    fn placed(&self, state: &State) -> Vec<Placed> {
        (0..self.len())
            .into_par_iter()
            .map(|s| {
                let mut p = self.base[s];
                for (d, wk) in self.modes[s].iter().zip(&state.weights) {
                    p += d * *wk;
                }
                let lift = if state.field.is_empty() {
                    0.0
                } else {
                    self.basis[s]
                        .iter()
                        .map(|&(c, b)| b * state.field[c])
                        .sum::<Real>()
                };
                (p, lift)
            })
            .collect()
    }

    /// Every sample's unit normal on the identity surface at `state` and its derivatives in
    /// the identity weights ([`Window::Lit`]): with `m = F_u × F_v` (`F = B + Σₖ wₖ Dₖ`),
    /// `n = m / |m|` and `∂n/∂wₖ = (I − n nᵀ) (Dₖ,ᵤ × F_v + F_u × Dₖ,ᵥ) / |m|`, turned toward
    /// the mean face's normal; and each photo's normals, those of the identity surface with
    /// the photo's expression `Eᵢ` (`(F + Eᵢ)_u × (F + Eᵢ)_v`, normalised; the identity's
    /// normals for every photo without expressions). The field's lift is left out.
    ///
    /// The derivatives are the identity surface's, not each photo's: the Gauss-Newton
    /// equations share one Jacobian of the normal among the photos that see a sample
    /// ([`Level::add_sample`]); the cost itself shades each photo with its own normals.
    /// Without `derivatives` the derivatives are left empty (what visibility needs).
    fn shape_normals(&self, state: &State, derivatives: bool) -> ShapeNormals {
        let per_sample: Vec<(NormalJet, Vec<Vector3<Real>>)> = self
            .partials
            .par_iter()
            .zip(&self.normals)
            .enumerate()
            .map(|(s, (([base_u, base_v], modes), mean_normal))| {
                let (mut fu, mut fv) = (*base_u, *base_v);
                for ([du, dv], w) in modes.iter().zip(&state.weights) {
                    fu += du * *w;
                    fv += dv * *w;
                }
                let m = fu.cross(&fv);
                let length = m.norm();
                if length.is_nan() || length <= 1e-12 {
                    let photos = vec![*mean_normal; self.expression_partials.len()];
                    return ((*mean_normal, vec![Vector3::zeros(); modes.len()]), photos);
                }
                let sign = if m.dot(mean_normal) < 0.0 { -1.0 } else { 1.0 };
                let n = m * (sign / length);
                let project = |d: Vector3<Real>| (d - n * n.dot(&d)) * (sign / length);
                let derivatives = modes
                    .iter()
                    .take(if derivatives { state.weights.len() } else { 0 })
                    .map(|[du, dv]| project(du.cross(&fv) + fu.cross(dv)))
                    .collect();
                let photos = self
                    .expression_partials
                    .iter()
                    .enumerate()
                    .map(|(i, photo)| {
                        let [mut eu, mut ev] = photo[s];
                        let shifts = state.shifts.get(i).map_or(&[][..], Vec::as_slice);
                        for ([du, dv], shift) in self.photo_partials[s].iter().zip(shifts) {
                            eu += du * *shift;
                            ev += dv * *shift;
                        }
                        let m = (fu + eu).cross(&(fv + ev));
                        let length = m.norm();
                        if length.is_nan() || length <= 1e-12 {
                            n
                        } else {
                            m * (if m.dot(mean_normal) < 0.0 { -1.0 } else { 1.0 } / length)
                        }
                    })
                    .collect();
                ((n, derivatives), photos)
            })
            .collect();
        let (identity, by_sample): (Vec<_>, Vec<_>) = per_sample.into_iter().unzip();
        let photos = (0..self.expression_partials.len())
            .map(|i| by_sample.iter().map(|photos| photos[i]).collect())
            .collect();
        ShapeNormals { identity, photos }
    }
}

/// A unit normal and its derivatives in the identity weights.
type NormalJet = (Vector3<Real>, Vec<Vector3<Real>>);

/// The shape's own normals at a state ([`Samples::shape_normals`]).
struct ShapeNormals {
    /// Per sample: the identity surface's unit normal and its derivatives in the identity
    /// weights.
    identity: Vec<NormalJet>,
    /// Per photo and sample (`[i][s]`): the normal with the photo's expression; empty
    /// without expressions.
    photos: Vec<Vec<Vector3<Real>>>,
}

/// How a photo's intensities are normalised at one sample: `N = (I − mean) · inverse`, and
/// the derivative of `N` in the sample's normal per unit of `I` (`Window::Lit`; zero for the
/// others).
#[derive(Clone, Copy)]
struct Normaliser {
    mean: Real,
    inverse: Real,
    /// `∂N/∂n / I`.
    d_normal: Vector3<Real>,
}

/// Every photo's [`Normaliser`]s at a state (`scales[i][s]`) and, for [`Window::Lit`],
/// every sample's normal derivatives in the identity weights (`normal_modes[s][k]`; empty
/// for the other windows, and each sample's empty where the cost alone is wanted).
struct Normalisation {
    scales: Vec<Vec<Normaliser>>,
    normal_modes: Vec<Vec<Vector3<Real>>>,
}

/// A sample's identity point and its field lift ([`Samples::placed`]).
type Placed = (Point3<Real>, Real);

/// Each sample's neighbours within two window deviations on the sample grid (`cells`, the
/// samples' grid coordinates), with their Gaussian weights: the window of the local
/// normalisation, `window_eyes` eye distances (50 units each) or one and a half samples'
/// spacings, whichever is larger.
fn neighbours(cells: &[(i64, i64)], spacing: Real, window_eyes: Real) -> Vec<Vec<(usize, Real)>> {
    let sigma = (window_eyes * 50.0).max(1.5 * spacing) / spacing;
    let reach = (2.0 * sigma).ceil() as i64;
    let index: std::collections::HashMap<(i64, i64), usize> =
        cells.iter().enumerate().map(|(s, &c)| (c, s)).collect();
    cells
        .iter()
        .map(|&(a, b)| {
            let mut out = Vec::new();
            for da in -reach..=reach {
                for db in -reach..=reach {
                    let d2 = (da * da + db * db) as Real;
                    if d2 > (reach * reach) as Real {
                        continue;
                    }
                    if let Some(&t) = index.get(&(a + da, b + db)) {
                        out.push((t, (-d2 / (2.0 * sigma * sigma)).exp()));
                    }
                }
            }
            out
        })
        .collect()
}

/// Each photo's shading `Sᵢₛ = lᵢ · (1, nₛ)` at every sample it sees ([`Window::Shaded`]):
/// first-order spherical-harmonic lighting `lᵢ` (four coefficients, in the face's frame: each
/// photo has its own light, so the camera's rotation is absorbed in `lᵢ`) over the mean face's
/// normals `nₛ`, with an albedo `aₛ` per sample shared by the photos: `Iᵢₛ ≈ aₛ Sᵢₛ`.
///
/// The albedo is eliminated exactly. Two photos that see a sample agree on it when
/// `Iᵢₛ Sⱼₛ − Iⱼₛ Sᵢₛ = 0`, which is linear in the lights, so all the lights at once come from
/// one generalised symmetric eigenproblem (`4 × photos` square) over those equations' squares
/// summed over the pairs and samples (per sample, `Σᵢⱼ cᵢ cⱼ (Iᵢ Sⱼ − Iⱼ Sᵢ)²` sums in closed
/// form to `2 (Σᵢ cᵢ Iᵢ²)(Σⱼ cⱼ Sⱼ²) − 2 (Σᵢ cᵢ Iᵢ Sᵢ)²`, so the cost is linear in the
/// pairs). Shadows and highlights the model cannot follow are down-weighted over
/// [`SHADING_ROUNDS`] rounds by a Cauchy weight on each intensity's relative residual about
/// `aₛ Sᵢₛ`. Each photo's `S` is scaled to a mean of 1 over the samples it sees and floored at
/// 0.1: a sample the model puts in full shade keeps a finite correction.
///
/// Measured on the way (`tools/photo_eval`, every refinement kept, mean ratio to the mean
/// face for 2 / 3 / 4 / 8 / 16 photos): this fit 0.89 / 0.82 / 0.82 / 0.74 / 0.69. Six
/// rounds of alternating albedo and lights from ambient light (which converges slowly: 15%
/// errors left after 50 rounds on the unit test's exact data) gave 0.85 / 0.78 / 0.76 / 0.70
/// / 0.65, yet worse on the real scan's sets (8 photos: 0.93 against the image window's
/// 0.88); the pairs' disagreement minimised without its normalisation 0.91 / 0.87 / 0.87 /
/// 0.82 / 0.80 (it prefers lights that shade the whole face dark); a second-order lighting
/// (nine coefficients, alternating) was no better on the scan. A prior toward ambient light strong enough to matter (1% of the ambient weight
/// on each direction) already moves the unit test's exact answer by 15%: the photos say
/// little about the directional light over a face's narrow range of normals.
fn fit_shading<N: AsRef<[Vector3<Real>]> + Sync>(
    raw: &[Vec<Option<Real>>],
    visibility: &[Vec<Real>],
    normals: &[N],
) -> Vec<Vec<Real>> {
    shading_of(
        fit_lights(raw, visibility, normals).as_deref(),
        raw,
        visibility,
        normals,
    )
    .into_iter()
    .map(|photo| photo.into_iter().map(|(shade, _)| shade).collect())
    .collect()
}

/// Each photo's shading at every sample under `lights` ([`fit_lights`]; all 1 without
/// them) and its derivative in the sample's normal: `Sᵢₛ = max(lᵢ · (1, nₛ) / l̄ᵢ, 0.1)`
/// with `l̄ᵢ` the photo's mean of `lᵢ · (1, nₛ)` over the samples it sees, and
/// `∂Sᵢₛ/∂nₛ = (lᵢ,ₓ, lᵢ,ᵧ, lᵢ,𝓏) / l̄ᵢ` (zero where the floor holds it).
fn shading_of<N: AsRef<[Vector3<Real>]>>(
    lights: Option<&[nalgebra::Vector4<Real>]>,
    raw: &[Vec<Option<Real>>],
    visibility: &[Vec<Real>],
    normals: &[N],
) -> Vec<Vec<(Real, Vector3<Real>)>> {
    let n = normals.first().map_or(0, |photo| photo.as_ref().len());
    let Some(lights) = lights else {
        return vec![vec![(1.0, Vector3::zeros()); n]; raw.len()];
    };
    lights
        .iter()
        .zip(normals)
        .enumerate()
        .map(|(i, (light, normals))| {
            let shade: Vec<Real> = normals
                .as_ref()
                .iter()
                .map(|v| light.dot(&nalgebra::Vector4::new(1.0, v.x, v.y, v.z)))
                .collect();
            let (mut total, mut sum) = (0.0, 0.0);
            for s in 0..n {
                if raw[i][s].is_some() {
                    total += visibility[i][s];
                    sum += visibility[i][s] * shade[s];
                }
            }
            let mean = if total > 0.0 && sum > 0.0 {
                sum / total
            } else {
                1.0
            };
            let slope = light.fixed_rows::<3>(1) / mean;
            shade
                .iter()
                .map(|v| {
                    let v = v / mean;
                    if v > 0.1 {
                        (v, slope)
                    } else {
                        (0.1, Vector3::zeros())
                    }
                })
                .collect()
        })
        .collect()
}

/// The lights of [`fit_shading`]; `None` when the photos say too little to fit them.
fn fit_lights<N: AsRef<[Vector3<Real>]> + Sync>(
    raw: &[Vec<Option<Real>>],
    visibility: &[Vec<Real>],
    normals: &[N],
) -> Option<Vec<nalgebra::Vector4<Real>>> {
    let photos = raw.len();
    let n = normals.first().map_or(0, |photo| photo.as_ref().len());
    if normals.len() != photos || normals.iter().any(|photo| photo.as_ref().len() != n) {
        return None;
    }
    // Photo `i`'s lighting basis at sample `s`: `(1, nᵢₛ)`.
    let basis = |i: usize, s: usize| {
        let v = normals[i].as_ref()[s];
        nalgebra::Vector4::new(1.0, v.x, v.y, v.z)
    };
    let dim = 4 * photos;
    // Per photo and sample: the visibility times the robust weight.
    let mut weights: Vec<Vec<Real>> = raw
        .iter()
        .zip(visibility)
        .map(|(values, seen)| {
            values
                .iter()
                .zip(seen)
                .map(|(v, c)| if v.is_some() { c.max(0.0) } else { 0.0 })
                .collect()
        })
        .collect();
    let mut lights = vec![nalgebra::Vector4::new(1.0, 0.0, 0.0, 0.0); photos];
    for round in 0..SHADING_ROUNDS {
        if round > 0 {
            reweight(&mut weights, raw, visibility, &lights, &basis);
        }
        // The pairs' disagreement is `2 (D − V)` in the lights, `D` block diagonal
        // (`Σₛ (Σᵢ cᵢ Iᵢ²) cⱼ hⱼ hⱼᵀ` per photo `j`, `hᵢ = (1, nᵢₛ)` over photo `i`'s normals)
        // and `V = Σₛ v vᵀ`, `v = (cᵢ Iᵢ hᵢ)ᵢ`; its ratio to `D` is the weighted `sin²` of the
        // angle between each sample's intensities and its shadings, so the lights maximise
        // `Lᵀ V L / Lᵀ D L`: a generalised eigenproblem. (The plain smallest eigenvector of
        // `D − V` prefers lights that shade the whole face dark, `1 − n_z` being nearly zero on
        // a face seen from the front.)
        // The same lights whatever the threads ([`in_fixed_chunks`]).
        let parts: Vec<(DMatrix<Real>, DMatrix<Real>)> = in_fixed_chunks(n, |samples| {
            let mut d = DMatrix::<Real>::zeros(dim, dim);
            let mut q = DMatrix::<Real>::zeros(dim, dim);
            let mut v = DVector::<Real>::zeros(dim);
            for s in samples {
                let seen: Vec<(usize, Real, Real)> = (0..photos)
                    .filter_map(|i| {
                        let w = weights[i][s];
                        (w > 0.0).then(|| raw[i][s].map(|value| (i, w, value)))?
                    })
                    .collect();
                if seen.len() < 2 {
                    continue;
                }
                let squares: Real = seen.iter().map(|&(_, w, value)| w * value * value).sum();
                v.fill(0.0);
                for &(i, w, value) in &seen {
                    let h = basis(i, s);
                    let mut block = d.fixed_view_mut::<4, 4>(4 * i, 4 * i);
                    block += h * h.transpose() * (squares * w);
                    v.fixed_rows_mut::<4>(4 * i).copy_from(&(h * (w * value)));
                }
                for &(i, _, _) in &seen {
                    let vi = v.fixed_rows::<4>(4 * i).into_owned();
                    for &(j, _, _) in &seen {
                        let vj = v.fixed_rows::<4>(4 * j).into_owned();
                        let mut block = q.fixed_view_mut::<4, 4>(4 * i, 4 * j);
                        block += vi * vj.transpose();
                    }
                }
            }
            (d, q)
        });
        let (mut d, mut q) = (DMatrix::<Real>::zeros(dim, dim), DMatrix::<Real>::zeros(dim, dim));
        for (pd, pq) in parts {
            d += pd;
            q += pq;
        }
        let trace = d.trace();
        if !(trace > 0.0 && trace.is_finite()) {
            return None;
        }
        // A faint ridge keeps `D` invertible where a photo sees too little.
        for k in 0..dim {
            d[(k, k)] += 1e-9 * trace / dim as Real;
        }
        let inverse = d.cholesky()?.l().try_inverse()?;
        let reduced = &inverse * &q * inverse.transpose();
        let reduced = (&reduced + reduced.transpose()) * 0.5;
        let eigen = reduced.symmetric_eigen();
        let largest = eigen
            .eigenvalues
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map_or(0, |(k, _)| k);
        let vector = inverse.transpose() * eigen.eigenvectors.column(largest);
        let mut found: Vec<nalgebra::Vector4<Real>> = (0..photos)
            .map(|i| vector.fixed_rows::<4>(4 * i).into_owned())
            .collect();
        // The sign: shading is positive on the whole.
        let total: Real = (0..n)
            .map(|s| {
                found
                    .iter()
                    .enumerate()
                    .map(|(i, l)| weights[i][s] * l.dot(&basis(i, s)))
                    .sum::<Real>()
            })
            .sum();
        if total < 0.0 {
            found.iter_mut().for_each(|l| *l = -*l);
        }
        lights = found;
    }
    Some(lights)
}

/// The robust weights of [`fit_shading`] under `lights`: each intensity's visibility times a
/// Cauchy weight on its relative residual about its sample's albedo times its shading.
fn reweight(
    weights: &mut [Vec<Real>],
    raw: &[Vec<Option<Real>>],
    visibility: &[Vec<Real>],
    lights: &[nalgebra::Vector4<Real>],
    basis: &impl Fn(usize, usize) -> nalgebra::Vector4<Real>,
) {
    let photos = lights.len();
    for s in 0..weights.first().map_or(0, Vec::len) {
        let (mut top, mut bottom) = (0.0, 0.0);
        for i in 0..photos {
            if let Some(value) = raw[i][s] {
                let shade = lights[i].dot(&basis(i, s));
                let c = visibility[i][s].max(0.0);
                top += c * value * shade;
                bottom += c * shade * shade;
            }
        }
        if bottom <= 1e-12 {
            continue;
        }
        let albedo = top / bottom;
        for i in 0..photos {
            if let Some(value) = raw[i][s] {
                let residual = value - albedo * lights[i].dot(&basis(i, s));
                weights[i][s] = visibility[i][s].max(0.0) * cauchy(residual, 0.1 * value.abs().max(1e-3));
            }
        }
    }
}

/// Rounds of the photos' shading fit, each reweighting the intensities the model does not
/// explain ([`Window::Shaded`]).
const SHADING_ROUNDS: usize = 3;

/// The floor under a local deviation of intensity (intensities in `[0, 1]`): flat skin is
/// not amplified into noise.
const DEVIATION_FLOOR: Real = 0.02;

/// What the landmarks contribute: the space's structure modes and each photo's expression.
struct Landmarks<'a> {
    base: Vec<Point3<Real>>,
    /// `modes[j][k]`.
    modes: Vec<Vec<Vector3<Real>>>,
    expression: Vec<Vec<Vector3<Real>>>,
    /// `photo_modes[j][l]`: the structure's displacement by each expression the photos shift
    /// on their own ([`Problem::photo_shifted`]).
    photo_modes: Vec<Vec<Vector3<Real>>>,
    views: &'a [RefineView<'a>],
    point_weights: &'a [Real; POINT_COUNT],
    /// Per photo: the fixed unit `uᵢ` (its starting scale).
    units: Vec<Real>,
}

/// The state the refinement moves.
#[derive(Clone)]
struct State {
    weights: Vec<Real>,
    cameras: Vec<RefinedCamera>,
    /// Per photo, its own shift of each expression [`Problem::photo_shifted`] names
    /// ([`RefineOptions::expression_photos`]; every photo's empty without it).
    shifts: Vec<Vec<Real>>,
    /// The control points' depth displacements (empty without [`RefineOptions::field`]).
    field: Vec<Real>,
}

impl State {
    /// The state moved by `step`: the identity, then each photo's block (its camera's
    /// [`CAMERA`] unknowns, then its expression shifts), then the field.
    fn moved(&self, step: &DVector<Real>) -> State {
        let k = self.weights.len();
        let width = self.photo_width();
        let f = k + width * self.cameras.len();
        let block = |i: usize| &step.as_slice()[k + width * i..k + width * (i + 1)];
        State {
            weights: self.weights.iter().zip(step.iter()).map(|(w, d)| w + d).collect(),
            cameras: self
                .cameras
                .iter()
                .enumerate()
                .map(|(i, c)| c.moved(&block(i)[..CAMERA]))
                .collect(),
            shifts: self
                .shifts
                .iter()
                .enumerate()
                .map(|(i, own)| own.iter().zip(&block(i)[CAMERA..]).map(|(a, d)| a + d).collect())
                .collect(),
            field: self
                .field
                .iter()
                .zip(&step.as_slice()[f..])
                .map(|(a, d)| a + d)
                .collect(),
        }
    }

    /// The unknowns of each photo's block: its camera's, then its expression shifts.
    fn photo_width(&self) -> usize {
        CAMERA + self.shifts.first().map_or(0, Vec::len)
    }

    /// Where the field's unknowns begin: after the identity's and every photo's block.
    fn field_start(&self) -> usize {
        self.weights.len() + self.photo_width() * self.cameras.len()
    }

    fn unknowns(&self) -> usize {
        self.field_start() + self.field.len()
    }
}

/// One photo's view of one sample, linearised.
struct Seen {
    photo: usize,
    weight: Real,
    value: Real,
    /// `∂N/∂X`, `∂N/∂n` (the sample's normal, [`Window::Lit`]; zero for the other windows)
    /// and `∂N` in the photo's own unknowns, its block (`∂N/∂w` is `∂N/∂X` through the
    /// sample's modes and `∂N/∂n` through its normal's derivatives).
    d_point: Vector3<Real>,
    d_normal: Vector3<Real>,
    /// `∂N/∂camera`, then `∂N/∂δᵢₗ` for the photo's own expression shifts (`∂N/∂X` through
    /// the expression's displacement at the sample; its normal's change is left out, as the
    /// identity's normal derivatives are shared among the photos), zero beyond the block's
    /// width ([`State::photo_width`]).
    d_photo: [Real; PHOTO_MAX],
}

/// The problem at one level.
struct Level<'a> {
    images: Vec<LevelImage>,
    samples: Samples,
    landmarks: &'a Landmarks<'a>,
    /// Each weight's prior deviation ([`Problem::sigma_prior`]).
    sigma_prior: &'a [Real],
    /// The range of each weight after the identity's ([`Problem::shift_limits`]).
    shift_limits: &'a [(Real, Real)],
    /// Per photo, the range of each of its own expression shifts
    /// ([`Problem::photo_shift_limits`]).
    photo_shift_limits: &'a [Vec<(Real, Real)>],
    /// Each photo's `κ` prior centre ([`Problem::perspective_prior`]).
    perspective_prior: &'a [Real],
    options: &'a RefineOptions,
    /// Each photo's weight ([`RefineOptions::photo_weights`]; all 1 otherwise), folded into
    /// its visibility.
    photo_weights: Vec<Real>,
    /// The field's prior's stencils ([`field_stencils`]; empty when the level fits no field).
    field_stencils: Vec<Vec<(usize, Real)>>,
    /// The field block's half-bandwidth ([`field_bandwidth`]; 0 without a field).
    field_bandwidth: usize,
    /// Hold the face (identity weights and field): only the cameras move.
    face_held: bool,
    /// Per photo, hold its camera (empty: none held).
    cameras_held: Vec<bool>,
}

/// The summed weight of the photos that see a sample and the weighted mean of their
/// normalised intensities there (the eliminated albedo); `None` for fewer than two photos.
fn agreement(seen: &[Seen]) -> Option<(Real, Real)> {
    if seen.len() < 2 {
        return None;
    }
    let total: Real = seen.iter().map(|v| v.weight).sum();
    let mean = seen.iter().map(|v| v.weight * v.value).sum::<Real>() / total;
    Some((total, mean))
}

/// What [`Level::add_sample`] takes besides the modes: the sample's field basis values, the
/// views that see it, their summed weight and weighted mean ([`agreement`]), and the
/// residuals' scale `β / σ²` with the Cauchy loss's parameter.
type SampleTerms<'a> = (&'a [(usize, Real)], &'a [Seen], (Real, Real), (Real, Real));

/// A view's derivative in the sample's `D` geometric unknowns: `∂N/∂X` (`D = 3`), then
/// `∂N/∂n` (`D = 6`, [`Window::Lit`]).
fn jet<const D: usize>(v: &Seen) -> SVector<Real, D> {
    SVector::from_fn(|r, _| if r < 3 { v.d_point[r] } else { v.d_normal[r - 3] })
}

/// `f` over `0..n` cut into eight fixed chunks (fewer when `n` is small), the chunks in
/// parallel, the results in the chunks' order: sums taken in order within each chunk and then
/// over the results are the same whatever the threads.
fn in_fixed_chunks<T: Send>(n: usize, f: impl Fn(std::ops::Range<usize>) -> T + Sync) -> Vec<T> {
    let chunk = n.div_ceil(8).max(1);
    (0..n.div_ceil(chunk))
        .into_par_iter()
        .map(|c| f(c * chunk..((c + 1) * chunk).min(n)))
        .collect()
}

/// Cauchy weight of a residual of scale `c`.
fn cauchy(r: Real, c: Real) -> Real {
    1.0 / (1.0 + (r / c) * (r / c))
}

impl Level<'_> {
    /// Which photos see which samples under `state`: per photo, a weight per sample (how
    /// squarely it is seen, 0 when facing away or hidden), times the photo's weight. How
    /// squarely: by the shape's own normals in the photo (its expression's,
    /// [`Samples::shape_normals`]) where the level keeps them ([`Window::Lit`]), else by the
    /// mean face's.
    fn visibility(&self, state: &State) -> Vec<Vec<Real>> {
        let placed = self.samples.placed(state);
        let shape = (!self.samples.partials.is_empty()).then(|| self.samples.shape_normals(state, false));
        let normal = |i: usize, s: usize| match &shape {
            Some(shape) => shape.photos.get(i).map_or(shape.identity[s].0, |photo| photo[s]),
            None => self.samples.normals[s],
        };
        state
            .cameras
            .par_iter()
            .enumerate()
            .map(|(i, camera)| {
                let image = &self.images[i];
                let n = self.samples.len();
                let mut seen = vec![0.0; n];
                let mut places = Vec::with_capacity(n);
                for (s, item) in seen.iter_mut().enumerate() {
                    let x = self.samples.point(&placed, state, s, i);
                    let Some(Projected { q, p, .. }) = camera.project(&x) else {
                        places.push(None);
                        continue;
                    };
                    let facing = (camera.rotation * normal(i, s)).dot(&camera.towards_from(&q));
                    *item = ((facing - 0.15) / 0.35).clamp(0.0, 1.0);
                    places.push(Some((image.crop_of(&p), q.z)));
                }
                // The depth test: a grid of cells about twice the samples' spacing in the crop;
                // a sample more than two spacings behind the front-most in its cell is hidden.
                let cell = (2.0 * self.samples.spacing * camera.scale * image.factor).max(1.0);
                let (cw, ch) = (
                    (image.width as Real / cell).ceil() as usize + 1,
                    (image.height as Real / cell).ceil() as usize + 1,
                );
                let mut front = vec![Real::NEG_INFINITY; cw * ch];
                let index = |c: &Vector2<Real>| -> Option<usize> {
                    let (a, b) = ((c.x / cell).floor(), (c.y / cell).floor());
                    (a >= 0.0 && b >= 0.0 && (a as usize) < cw && (b as usize) < ch)
                        .then(|| b as usize * cw + a as usize)
                };
                for (place, w) in places.iter().zip(&seen) {
                    if let (Some((c, z)), true) = (place, *w > 0.0)
                        && let Some(k) = index(c)
                    {
                        front[k] = front[k].max(*z);
                    }
                }
                for (place, w) in places.iter().zip(seen.iter_mut()) {
                    match place {
                        Some((c, z)) => match index(c) {
                            Some(k) if *z >= front[k] - 2.0 * self.samples.spacing && image.contains(c) => {}
                            _ => *w = 0.0,
                        },
                        None => *w = 0.0,
                    }
                }
                let weight = self.photo_weights[i];
                seen.iter_mut().for_each(|c| *c *= weight);
                seen
            })
            .collect()
    }

    /// Each photo's weight from how well it agrees with the others at `state`: its mean
    /// squared disagreement about the samples' means, against the median photo's, `wᵢ =
    /// min(1, median / msdᵢ)`. A photo that disagrees for reasons other than shape (another
    /// light, an expression, make-up) counts less; the photos that agree as most do count
    /// fully.
    fn photo_weights(&self, state: &State) -> Vec<Real> {
        let visibility = self.visibility(state);
        let per_sample = self.per_sample(state, &visibility, |seen, _, mean| {
            seen.iter()
                .map(|v| (v.photo, v.weight, v.weight * (v.value - mean).powi(2)))
                .collect::<Vec<_>>()
        });
        let mut sums = vec![(0.0, 0.0); state.cameras.len()];
        for (i, weight, square) in per_sample.into_iter().flatten().flatten() {
            sums[i].0 += weight;
            sums[i].1 += square;
        }
        let msd: Vec<Option<Real>> = sums
            .iter()
            .map(|&(total, sum)| (total > 0.0).then(|| sum / total))
            .collect();
        let mut sorted: Vec<Real> = msd.iter().flatten().copied().collect();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let Some(&median) = sorted.get(sorted.len() / 2) else {
            return vec![1.0; state.cameras.len()];
        };
        msd.iter()
            .map(|m| m.map_or(1.0, |m| if m > median { median / m } else { 1.0 }))
            .collect()
    }

    /// Per photo and sample at `state` (its samples `placed`, [`Samples::placed`]): how the
    /// photo's intensity there is normalised, `N = (I − mean) · inverse`. With a window on the
    /// surface, the local mean and inverse deviation of the photo's intensities over the
    /// sample's neighbours that the photo sees: it covers the same part of the face in every
    /// photo however obliquely each sees it (a window in the image would not, and measurably
    /// biased the shape; [`Window::Image`]'s crops are normalised already). With
    /// [`Window::Lit`], [`Level::lit`]'s (with the normals' derivatives in the identity
    /// weights when `derivatives`, which only the normal equations need).
    fn normalisers(
        &self,
        state: &State,
        placed: &[Placed],
        visibility: &[Vec<Real>],
        derivatives: bool,
    ) -> Normalisation {
        let plain = |scales: Vec<Vec<Normaliser>>| Normalisation {
            scales,
            normal_modes: Vec::new(),
        };
        if self.options.window == Window::Image {
            // The images are normalised already.
            let identity = Normaliser {
                mean: 0.0,
                inverse: 1.0,
                d_normal: Vector3::zeros(),
            };
            return plain(vec![vec![identity; self.samples.len()]; state.cameras.len()]);
        }
        let raw: Vec<Vec<Option<Real>>> = state
            .cameras
            .par_iter()
            .enumerate()
            .map(|(i, camera)| {
                let image = &self.images[i];
                (0..self.samples.len())
                    .map(|s| {
                        if visibility[i][s] <= 0.0 {
                            return None;
                        }
                        let x = self.samples.point(placed, state, s, i);
                        let projected = camera.project(&x)?;
                        image.sample(&image.crop_of(&projected.p)).map(|(v, _)| v)
                    })
                    .collect()
            })
            .collect();
        if self.options.window == Window::Lit {
            return self.lit(state, &raw, visibility, derivatives);
        }
        let shading = match self.options.window {
            Window::Shaded => fit_shading(&raw, visibility, &vec![&self.samples.normals[..]; raw.len()]),
            _ => vec![vec![1.0; self.samples.len()]; raw.len()],
        };
        let scales = raw
            .par_iter()
            .zip(&shading)
            .map(|(raw, shading)| {
                // The normalisation of `I / S` as one of `I`: `(I / S − m) · d = (I − m S) · d / S`.
                self.samples
                    .neighbours
                    .iter()
                    .enumerate()
                    .map(|(s, near)| {
                        let (mut total, mut sum, mut squares) = (0.0, 0.0, 0.0);
                        for &(t, w) in near {
                            if let Some(v) = raw[t] {
                                let v = v / shading[t];
                                total += w;
                                sum += w * v;
                                squares += w * v * v;
                            }
                        }
                        let (mean, inverse) = if total <= 0.0 {
                            (0.0, 0.0)
                        } else {
                            let mean = sum / total;
                            let variance = (squares / total - mean * mean).max(0.0);
                            let inverse = 1.0 / (variance + DEVIATION_FLOOR * DEVIATION_FLOOR).sqrt();
                            (mean * shading[s], inverse / shading[s])
                        };
                        Normaliser {
                            mean,
                            inverse,
                            d_normal: Vector3::zeros(),
                        }
                    })
                    .collect()
            })
            .collect();
        plain(scales)
    }

    /// [`Window::Lit`]'s normalisation of the photos' (linear) intensities `raw` at `state`:
    /// each photo's lighting fitted over the shape's own normals and divided out, then the
    /// photo's gain and bias (its visibility-weighted mean `mᵢ` and deviation `dᵢ` of
    /// `I / S` over the samples it sees): `N = (I / S − mᵢ) / dᵢ = (I − mᵢ S) / (S dᵢ)`, and
    /// `∂N/∂n = −I / (S² dᵢ) · ∂S/∂n` ([`shading_of`]). The normals' derivatives
    /// (`normal_modes`) are left empty without `derivatives`.
    fn lit(
        &self,
        state: &State,
        raw: &[Vec<Option<Real>>],
        visibility: &[Vec<Real>],
        derivatives: bool,
    ) -> Normalisation {
        let ShapeNormals { identity, photos } = self.samples.shape_normals(state, derivatives);
        let (normals, normal_modes): (Vec<Vector3<Real>>, Vec<Vec<Vector3<Real>>>) =
            identity.into_iter().unzip();
        // Each photo shaded over its own normals (its expression's); the identity's without
        // expressions.
        let normals: Vec<&[Vector3<Real>]> = if photos.len() == raw.len() {
            photos.iter().map(Vec::as_slice).collect()
        } else {
            vec![&normals[..]; raw.len()]
        };
        // Each photo's light is fitted over its samples at full weight: a photo's weight
        // ([`RefineOptions::photo_weights`]) says how far its intensities are trusted for the
        // shape, and its light is its own either way. Fitted at the photo's weight instead, a
        // photo counting little has a light the joint fit hardly constrains, and an inverted
        // photo then pulled the face further off weighted than unweighted (five faces in
        // `tests/splineface/refine.rs`: 1.46 units from the truth against 0.91; now 1.00).
        let full: std::borrow::Cow<'_, [Vec<Real>]> = if self.photo_weights.iter().all(|&w| w == 1.0) {
            std::borrow::Cow::Borrowed(visibility)
        } else {
            std::borrow::Cow::Owned(
                visibility
                    .iter()
                    .zip(&self.photo_weights)
                    .map(|(seen, &w)| {
                        // A photo left out (weight 0) stays out.
                        seen.iter().map(|c| if w > 0.0 { c / w } else { *c }).collect()
                    })
                    .collect(),
            )
        };
        let lights = fit_lights(raw, &full, &normals);
        let shading = shading_of(lights.as_deref(), raw, &full, &normals);
        let scales = raw
            .iter()
            .zip(&shading)
            .zip(visibility)
            .map(|((raw, shading), seen)| {
                let (mut total, mut sum, mut squares) = (0.0, 0.0, 0.0);
                for ((value, (shade, _)), c) in raw.iter().zip(shading).zip(seen) {
                    if let Some(value) = value {
                        let v = value / shade;
                        total += c;
                        sum += c * v;
                        squares += c * v * v;
                    }
                }
                let (mean, deviation) = if total > 0.0 {
                    let mean = sum / total;
                    (mean, (squares / total - mean * mean).max(0.0).sqrt())
                } else {
                    (0.0, 1.0)
                };
                let inverse = 1.0 / deviation.max(DEVIATION_FLOOR);
                shading
                    .iter()
                    .map(|&(shade, slope)| Normaliser {
                        mean: mean * shade,
                        inverse: inverse / shade,
                        d_normal: -slope * (inverse / (shade * shade)),
                    })
                    .collect()
            })
            .collect();
        Normalisation { scales, normal_modes }
    }

    /// Sample `s` seen by the photos with weights `visibility`, linearised (with derivatives
    /// when `derivatives`), into `out` (cleared first; the callers keep one buffer for many
    /// samples rather than allocate one per sample).
    #[allow(clippy::too_many_arguments)]
    fn seen(
        &self,
        state: &State,
        placed: &[Placed],
        visibility: &[Vec<Real>],
        normalisation: &Normalisation,
        s: usize,
        derivatives: bool,
        out: &mut Vec<Seen>,
    ) {
        out.clear();
        for (i, camera) in state.cameras.iter().enumerate() {
            let c = visibility[i][s];
            if c <= 0.0 {
                continue;
            }
            let x = self.samples.point(placed, state, s, i);
            let Some(projected) = camera.project(&x) else {
                continue;
            };
            let p = projected.p;
            let image = &self.images[i];
            let Some((raw, raw_grad)) = image.sample(&image.crop_of(&p)) else {
                continue;
            };
            // The sample's normalisation is held while the geometry moves (recomputed at every
            // state the cost is taken at).
            let Normaliser {
                mean,
                inverse,
                d_normal,
            } = normalisation.scales[i][s];
            let (value, grad) = ((raw - mean) * inverse, raw_grad * inverse);
            let mut d_photo = [0.0; PHOTO_MAX];
            let mut d_point = Vector3::zeros();
            let d_normal = d_normal * raw;
            if derivatives {
                // ∂N/∂q = ∇N · ∂p/∂q; ∂q/∂x = R.
                let dn_dq = projected.dq.transpose() * grad;
                let dn_dx = camera.rotation.matrix().transpose() * dn_dq;
                d_point = dn_dx;
                let (rx, ry) = (projected.camera_row(0), projected.camera_row(1));
                for (t, d) in d_photo[..CAMERA].iter_mut().enumerate() {
                    *d = grad.x * rx[t] + grad.y * ry[t];
                }
                for (d, mode) in d_photo[CAMERA..].iter_mut().zip(&self.samples.photo_modes[s]) {
                    *d = dn_dx.dot(mode);
                }
            }
            out.push(Seen {
                photo: i,
                weight: c,
                value,
                d_point,
                d_normal,
                d_photo,
            });
        }
    }

    /// Per sample: the weighted sum of squares of the photos' normalised intensities about
    /// their mean, and the summed weights; `None` where fewer than two photos see it.
    fn disagreement(&self, state: &State, visibility: &[Vec<Real>]) -> Vec<Option<(Real, Real)>> {
        self.per_sample(state, visibility, |seen, total, mean| {
            let sum = seen
                .iter()
                .map(|v| v.weight * (v.value - mean).powi(2))
                .sum::<Real>();
            (sum, total)
        })
    }

    /// `f(seen, total, mean)` for every sample two photos or more see (the photos' views of
    /// it, their summed weight and their weighted mean, [`agreement`]), `None` for the others;
    /// in the samples' order whatever the threads.
    fn per_sample<T: Send>(
        &self,
        state: &State,
        visibility: &[Vec<Real>],
        f: impl Fn(&[Seen], Real, Real) -> T + Sync,
    ) -> Vec<Option<T>> {
        let placed = self.samples.placed(state);
        let normalisation = self.normalisers(state, &placed, visibility, false);
        (0..self.samples.len())
            .into_par_iter()
            .map_init(Vec::new, |seen, s| {
                self.seen(state, &placed, visibility, &normalisation, s, false, seen);
                let (total, mean) = agreement(seen)?;
                Some(f(seen, total, mean))
            })
            .collect()
    }

    /// The samples' values laid on their grid, rows from the bottom; NaN where no sample is.
    fn grid_of(&self, values: &[Real]) -> (usize, usize, Vec<Real>) {
        let width = self.samples.cells.iter().map(|c| c.0).max().unwrap_or(0) as usize + 1;
        let height = self.samples.cells.iter().map(|c| c.1).max().unwrap_or(0) as usize + 1;
        let mut grid = vec![Real::NAN; width * height];
        for (&(a, b), v) in self.samples.cells.iter().zip(values) {
            grid[b as usize * width + a as usize] = *v;
        }
        (width, height, grid)
    }

    /// The robust consistency cost.
    fn consistency_cost(&self, state: &State, visibility: &[Vec<Real>]) -> Real {
        let c = 2.0 * self.options.sigma;
        self.scaled_consistency(
            self.per_sample(state, visibility, |seen, _, mean| sample_cost(seen, mean, c))
                // Summed in order: the same result whatever the threads.
                .iter()
                .flatten()
                .sum::<Real>(),
        )
    }

    /// The consistency cost from its per-sample terms' sum ([`sample_cost`]): times `β / σ²`,
    /// in one order of operations for [`Level::consistency_cost`] and
    /// [`Level::normal_equations`], whose costs must agree to the bit.
    fn scaled_consistency(&self, sum: Real) -> Real {
        sum * self.options.beta / (self.options.sigma * self.options.sigma)
    }

    /// The whole cost.
    fn cost(&self, state: &State, visibility: &[Vec<Real>]) -> Real {
        self.consistency_cost(state, visibility)
            + self.landmarks.cost(state, self.options)
            + self.prior(state)
    }

    fn prior(&self, state: &State) -> Real {
        let identity: Real = state
            .weights
            .iter()
            .zip(self.sigma_prior)
            .map(|(w, s)| (w / s).powi(2))
            .sum();
        let field: Real = self.field_residuals(state).map(|r| r * r).sum();
        let photo_sigma = self.options.expression_photos.unwrap_or(1.0);
        let shifts: Real = state
            .shifts
            .iter()
            .flatten()
            .map(|d| (d / photo_sigma).powi(2))
            .sum();
        identity
            + field
            + shifts
            + state
                .cameras
                .iter()
                .zip(self.perspective_prior)
                .map(|(c, &centre)| perspective_residual(c.perspective, centre).powi(2))
                .sum::<Real>()
    }

    /// The field's prior's residuals at `state`, one per stencil of [`Level::field_stencils`]
    /// (none without a field).
    fn field_residuals<'s>(&'s self, state: &'s State) -> impl Iterator<Item = Real> + 's {
        self.field_stencils
            .iter()
            .map(|stencil| stencil.iter().map(|&(c, v)| v * state.field[c]).sum::<Real>())
    }

    /// Adds one sample's consistency residuals to the normal equations (the dense block's
    /// upper triangle, the cross and field blocks, the gradient). `(total, mean)` are the
    /// seeing views' summed weight and weighted mean ([`agreement`]); `(scale, c)` the
    /// residuals' scale `β / σ²` and the Cauchy loss's parameter.
    ///
    /// View `a`'s residual is `rootₐ (Nₐ − μ)`, `rootₐ² = ρₐ` its weight (visibility, scale and
    /// the loss's reweighting), with the views' weighted mean `μ = Σ sₐ Nₐ` eliminated (`sₐ` a
    /// view's share of the summed visibility): its Jacobian is its own less the mean's. With
    /// `qₐ = ∂Nₐ/∂X − Σ sᵦ ∂Nᵦ/∂X` and `Mₛ` the sample's `3 × k` mode displacements (the same
    /// for every view), `cₐ` the view's Jacobian in its photo's block (its camera's, then its
    /// own expression shifts': `width` unknowns per photo, [`Seen::d_photo`]) and `βₑ` the
    /// field's basis values, every block of the sample's Gram matrix is a small closed form
    /// ("camera" for a photo's block):
    ///
    /// ```text
    /// identity × identity   Mₛᵀ A Mₛ,                 A = Σ ρₐ qₐ qₐᵀ  (3 × 3)
    /// identity × camera b   (Mₛᵀ (ρ_b q_b − s_b u)) c_bᵀ,    u = Σ ρₐ qₐ
    /// identity × field      (Mₛᵀ A e_z) βᵀ
    /// camera b × camera b'  δ_bb' ρ_b c_b c_bᵀ + (S s_b s_b' − ρ_b s_b' − ρ_b' s_b) c_b c_b'ᵀ,  S = Σ ρₐ
    /// camera b × field      (ρ_b q_b,z − s_b u_z) c_b βᵀ
    /// field × field         A_zz β βᵀ
    /// ```
    ///
    /// and the gradient `Mₛᵀ b`, `(ρ_b r_b − s_b R) c_b` and `b_z β` with `b = Σ ρₐ rₐ qₐ`,
    /// `R = Σ ρₐ rₐ`. Forming every residual's full row and its Gram matrix, as the objective
    /// reads, cost about ten times as much with eight photos and sixty modes.
    ///
    /// `modes` are the sample's `k` mode displacements (the identity's columns come first),
    /// each with its normal's derivative below it for [`Window::Lit`] (`D = 6`; the views'
    /// `qₐ` then stack `∂N/∂X` and `∂N/∂n`, [`jet`], and `A` is `6 × 6`); `basis` the
    /// sample's field basis values (empty without a field), the field moving the point alone.
    fn add_sample<const D: usize>(
        modes: &[SVector<Real, D>],
        width: usize,
        (basis, seen, (total, mean), (scale, c)): SampleTerms<'_>,
        equations: &mut Equations,
    ) {
        let n = equations.dense();
        let field = n;
        let Equations { a: h, cross, band, g } = equations;
        let k = modes.len();
        let mean_point: SVector<Real, D> = seen.iter().map(|v| jet::<D>(v) * (v.weight / total)).sum();
        // Per view: its share, its weight ρ, its residual and its point Jacobian about the mean.
        let views: Vec<(Real, Real, Real, SVector<Real, D>)> = seen
            .iter()
            .map(|v| {
                let r = v.value - mean;
                (
                    v.weight / total,
                    scale * v.weight * cauchy(r, c),
                    r,
                    jet::<D>(v) - mean_point,
                )
            })
            .collect();
        let (mut a, mut b, mut u) = (
            nalgebra::SMatrix::<Real, D, D>::zeros(),
            SVector::<Real, D>::zeros(),
            SVector::<Real, D>::zeros(),
        );
        let (mut weight_sum, mut residual_sum) = (0.0, 0.0);
        for &(_, rho, r, q) in &views {
            a += q * q.transpose() * rho;
            b += q * (rho * r);
            u += q * rho;
            weight_sum += rho;
            residual_sum += rho * r;
        }
        let hs = h.as_mut_slice();
        // Identity × identity (column by column, the upper triangle) and its gradient.
        let t: Vec<SVector<Real, D>> = modes.iter().map(|m| a * m).collect();
        for (j, tj) in t.iter().enumerate() {
            let column = &mut hs[j * n..j * n + j + 1];
            for (entry, mi) in column.iter_mut().zip(modes) {
                *entry += mi.dot(tj);
            }
        }
        for (i, mi) in modes.iter().enumerate() {
            g[i] += mi.dot(&b);
        }
        // Identity × field, field × field, and the field's gradient.
        let az = a.column(2).into_owned();
        let maz: Vec<Real> = if basis.is_empty() {
            Vec::new()
        } else {
            modes.iter().map(|m| m.dot(&az)).collect()
        };
        for (e, &(cp, value)) in basis.iter().enumerate() {
            let row = &mut cross[cp * n..cp * n + k];
            for (entry, m) in row.iter_mut().zip(&maz) {
                *entry += m * value;
            }
            for &(other, other_value) in &basis[..=e] {
                band.add(cp, other, a[(2, 2)] * value * other_value);
            }
            g[field + cp] += b[2] * value;
        }
        for (x, (view, &(share_b, rho_b, r_b, q_b))) in seen.iter().zip(&views).enumerate() {
            let base = k + width * view.photo;
            let camera = &view.d_photo[..width];
            // Identity × this camera.
            let y = q_b * rho_b - u * share_b;
            let my: Vec<Real> = modes.iter().map(|m| m.dot(&y)).collect();
            for (t, d) in camera.iter().enumerate() {
                let column = &mut hs[(base + t) * n..(base + t) * n + k];
                for (entry, m) in column.iter_mut().zip(&my) {
                    *entry += m * d;
                }
            }
            // This camera × the cameras of the views before it and itself (photos in order,
            // so their columns come first).
            for (other, &(share_o, rho_o, _, _)) in seen[..=x].iter().zip(&views) {
                let other_base = k + width * other.photo;
                let coefficient = weight_sum * share_b * share_o - rho_b * share_o - rho_o * share_b;
                let diagonal = if other.photo == view.photo { rho_b } else { 0.0 };
                for (t, d) in camera.iter().enumerate() {
                    let column = &mut hs[(base + t) * n..(base + t + 1) * n];
                    let rows = if other.photo == view.photo { t + 1 } else { width };
                    for (o, od) in other.d_photo[..rows].iter().enumerate() {
                        column[other_base + o] += (coefficient + diagonal) * od * d;
                    }
                }
            }
            // This camera × the field.
            let cross_coefficient = rho_b * q_b[2] - share_b * u[2];
            for &(cp, value) in basis {
                let row = &mut cross[cp * n + base..cp * n + base + width];
                for (entry, d) in row.iter_mut().zip(camera) {
                    *entry += cross_coefficient * d * value;
                }
            }
            let gradient = rho_b * r_b - share_b * residual_sum;
            for (t, d) in camera.iter().enumerate() {
                g[base + t] += gradient * d;
            }
        }
    }

    /// The Gauss-Newton normal equations `(H, g)` at `state` (the cost's half-Hessian and
    /// half-gradient) and the cost there: the cost is
    /// [`Level::cost`]'s to the bit (the same per-sample terms from the same views, summed in
    /// the samples' order), taken in the same pass over the samples as the equations.
    fn normal_equations(&self, state: &State, visibility: &[Vec<Real>]) -> (Equations, Real) {
        let placed = self.samples.placed(state);
        let normalisation = self.normalisers(state, &placed, visibility, true);
        let k = state.weights.len();
        let n = state.unknowns();
        let field = state.field_start();
        let width = state.photo_width();
        let bandwidth = self.field_bandwidth;
        let zeros = || Equations::zeros(field, n - field, bandwidth);
        let scale = self.options.beta / (self.options.sigma * self.options.sigma);
        let c = 2.0 * self.options.sigma;
        // The same equations whatever the threads ([`in_fixed_chunks`]; the outputs are
        // byte-identical across thread counts).
        let parts: Vec<(Equations, Vec<Real>)> = in_fixed_chunks(self.samples.len(), |samples| {
            let mut equations = zeros();
            let mut costs = Vec::with_capacity(samples.len());
            let mut seen = Vec::new();
            for s in samples {
                self.seen(state, &placed, visibility, &normalisation, s, true, &mut seen);
                if let Some((total, mean)) = agreement(&seen) {
                    costs.push(sample_cost(&seen, mean, c));
                    let basis: &[(usize, Real)] = if state.field.is_empty() {
                        &[]
                    } else {
                        &self.samples.basis[s]
                    };
                    let terms = (basis, &seen[..], (total, mean), (scale, c));
                    match normalisation.normal_modes.get(s) {
                        // The modes move the sample's normal too ([`Window::Lit`]).
                        Some(normal_modes) => {
                            let modes: Vec<SVector<Real, 6>> = self.samples.modes[s]
                                .iter()
                                .zip(normal_modes)
                                .map(|(m, t)| SVector::<Real, 6>::new(m.x, m.y, m.z, t.x, t.y, t.z))
                                .collect();
                            Self::add_sample(&modes, width, terms, &mut equations);
                        }
                        None => Self::add_sample(&self.samples.modes[s], width, terms, &mut equations),
                    }
                }
            }
            (equations, costs)
        });
        let mut equations = zeros();
        let mut consistency = 0.0;
        for (part, costs) in parts {
            equations.add(&part);
            // One running sum in the samples' order, as `consistency_cost` sums.
            for cost in costs {
                consistency += cost;
            }
        }
        equations.fill_lower();
        for (stencil, residual) in self.field_stencils.iter().zip(self.field_residuals(state)) {
            for &(a, va) in stencil {
                equations.g[field + a] += va * residual;
                for &(b, vb) in stencil.iter().filter(|(b, _)| *b <= a) {
                    equations.add_field(a, b, va * vb);
                }
            }
        }
        let Equations { a: h, g, .. } = &mut equations;
        self.landmarks.normal_equations(state, self.options, h, g);
        for (m, s) in self.sigma_prior.iter().enumerate() {
            h[(m, m)] += 1.0 / (s * s);
            g[m] += state.weights[m] / (s * s);
        }
        let photo_sigma = self.options.expression_photos.unwrap_or(1.0);
        for (i, shifts) in state.shifts.iter().enumerate() {
            for (l, shift) in shifts.iter().enumerate() {
                let t = k + width * i + CAMERA + l;
                equations.a[(t, t)] += 1.0 / (photo_sigma * photo_sigma);
                equations.g[t] += shift / (photo_sigma * photo_sigma);
            }
        }
        for (i, camera) in state.cameras.iter().enumerate() {
            let t = k + width * i + 6;
            if self.options.perspective {
                let centre = self.perspective_prior[i];
                let d = 1.0 / (PERSPECTIVE_SPREAD * centre);
                equations.a[(t, t)] += d * d;
                equations.g[t] += d * perspective_residual(camera.perspective, centre);
            } else {
                // κ stays 0.
                equations.hold(t);
            }
        }
        // Holding the face holds every photo's expression shifts too: only the cameras move.
        let held_shifts = (0..state.cameras.len()).flat_map(|i| k + width * i + CAMERA..k + width * (i + 1));
        let held_face = (0..k)
            .chain(held_shifts)
            .chain(field..n)
            .filter(|_| self.face_held);
        let held_cameras = self
            .cameras_held
            .iter()
            .enumerate()
            .filter(|(_, held)| **held)
            .flat_map(|(i, _)| k + width * i..k + width * (i + 1));
        for t in held_face.chain(held_cameras) {
            equations.hold(t);
        }
        let cost = self.scaled_consistency(consistency)
            + self.landmarks.cost(state, self.options)
            + self.prior(state);
        (equations, cost)
    }

    /// The held-out photos' disagreement with the others at `state`: per sample two of the
    /// others see, the weighted squares of each held-out view's normalised intensity about
    /// the others' weighted mean, and their summed weight (summed in the samples' order).
    fn held_out_error(&self, state: &State, held_out: &[bool]) -> (Real, Real) {
        let visibility = self.visibility(state);
        // Every sample that counts is seen by three photos or more, so by two: per_sample's.
        self.per_sample(state, &visibility, |seen, _, _| {
            let (test, train): (Vec<&Seen>, Vec<&Seen>) = seen.iter().partition(|v| held_out[v.photo]);
            if train.len() < 2 || test.is_empty() {
                return (0.0, 0.0);
            }
            let total: Real = train.iter().map(|v| v.weight).sum();
            let mean = train.iter().map(|v| v.weight * v.value).sum::<Real>() / total;
            test.iter().fold((0.0, 0.0), |(sum, weight), v| {
                (sum + v.weight * (v.value - mean).powi(2), weight + v.weight)
            })
        })
        .into_iter()
        .flatten()
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1))
    }
}

/// The folds of [`RefineOptions::held_out`]: per fold, which photos it holds out. The photos
/// are ordered by yaw and dealt out in turn, so that every fold and every training set spans
/// the yaws: two folds for four photos or more, one photo at a time for three, none for two
/// (one photo cannot be compared with itself).
fn folds(cameras: &[RefinedCamera]) -> Vec<Vec<bool>> {
    let n = cameras.len();
    if n < 3 {
        return Vec::new();
    }
    // The direction the camera looks from, in the face's frame: its yaw about the face's up.
    let yaw = |c: &RefinedCamera| {
        let d = c.rotation.inverse() * Vector3::z();
        d.x.atan2(d.z)
    };
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| yaw(&cameras[a]).total_cmp(&yaw(&cameras[b])));
    let count = if n == 3 { 3 } else { 2 };
    (0..count)
        .map(|f| {
            let mut held = vec![false; n];
            for (rank, &i) in order.iter().enumerate() {
                held[i] = rank % count == f;
            }
            held
        })
        .collect()
}

/// The focal length the refinement takes a photo to have before its pixels say otherwise, in
/// the photo's longer side: a photo's distance is poorly seen in it (a nearer camera and a
/// deeper face look alike), so each `κ = 1/d` starts at, and is drawn toward, `s / f` with
/// `f` this focal length, with a deviation of 0.7 of that (the private `typical_perspective`
/// and `PERSPECTIVE_SPREAD`). 1.2 is between a phone's main camera (about 0.75: 26 mm in
/// 35 mm terms) and a portrait lens (1.4–2: 50–70 mm); faces are mostly photographed at or
/// above the former.
///
/// Measured by `tools/photo_eval` with `REFINE_DIAG` (every refinement kept; 80 sets of 2–16
/// photos of the seven subjects; mean ratio of the error to the landmark fit's): with the
/// former prior, `κ ~ N(0, (1/300)²)` from `κ = 0` (orthographic), 0.817, 19 sets more than 2%
/// worse than the landmark fit, the worst 1.27×, the Lee Perry-Smith scan's rendered sets
/// 1.06 on average, and the cameras' distances came out 1.5–30× the true ones or at infinity;
/// with this prior 0.800, 17, 1.16× and 0.99, the distances within about 2× of the truth. A
/// focal length of 1.5 gave 0.804; a deviation of 0.4, 0.802.
pub const TYPICAL_FOCAL: Real = 1.2;

/// The deviation of the `κ` prior, a fraction of its centre ([`TYPICAL_FOCAL`]): one
/// deviation spans focal lengths from about 0.7× to 3.3× the typical one.
const PERSPECTIVE_SPREAD: Real = 0.7;

/// `κ = s / f` for the camera's scale `s` and the typical focal length `f` in the photo's
/// pixels ([`TYPICAL_FOCAL`] times its longer side).
fn typical_perspective(camera: &RefinedCamera, image: &GreyImage) -> Real {
    let longer = image.width().max(image.height()) as Real;
    camera.scale / (TYPICAL_FOCAL * longer)
}

/// The `κ` prior's residual in deviations.
fn perspective_residual(perspective: Real, centre: Real) -> Real {
    (perspective - centre) / (PERSPECTIVE_SPREAD * centre)
}

impl Landmarks<'_> {
    fn residuals(&self, state: &State, i: usize) -> Vec<Option<(Vector2<Real>, Projected)>> {
        let camera = &state.cameras[i];
        (0..POINT_COUNT)
            .map(|j| {
                let mut x = self.base[j];
                for (d, w) in self.modes[j].iter().zip(&state.weights) {
                    x += d * *w;
                }
                if let Some(e) = self.expression.get(i) {
                    x += e[j];
                }
                for (d, shift) in self.photo_modes[j].iter().zip(&state.shifts[i]) {
                    x += d * *shift;
                }
                camera
                    .project(&x)
                    .map(|projected| ((projected.p - self.views[i].points[j]) / self.units[i], projected))
            })
            .collect()
    }

    fn cost(&self, state: &State, options: &RefineOptions) -> Real {
        let mut sum = 0.0;
        for i in 0..state.cameras.len() {
            for (r, w) in self.residuals(state, i).iter().zip(self.point_weights) {
                sum += w * r.as_ref().map_or(1e6, |(r, _)| r.norm_squared());
            }
        }
        sum / (options.noise * options.noise)
    }

    /// Weighted RMS over all photos, canonical units.
    fn rms(&self, state: &State) -> Real {
        let total: Real = self.point_weights.iter().sum();
        let mut sum = 0.0;
        for i in 0..state.cameras.len() {
            for (r, w) in self.residuals(state, i).iter().zip(self.point_weights) {
                sum += w * r.as_ref().map_or(0.0, |(r, _)| r.norm_squared());
            }
        }
        (sum / (total * state.cameras.len() as Real)).sqrt()
    }

    fn normal_equations(
        &self,
        state: &State,
        options: &RefineOptions,
        h: &mut DMatrix<Real>,
        g: &mut DVector<Real>,
    ) {
        let k = state.weights.len();
        let width = state.photo_width();
        let inv = 1.0 / (options.noise * options.noise);
        // A residual's row is non-zero on the identity weights and its photo's block only: its
        // outer product goes into those four blocks alone (the rest of `H` would gain exact
        // zeros), a sixth of the whole matrix with 8 photos and less with more.
        let mut identity = DVector::<Real>::zeros(k);
        let mut own = DVector::<Real>::zeros(width);
        for (i, camera) in state.cameras.iter().enumerate() {
            let base = k + width * i;
            for (j, r) in self.residuals(state, i).into_iter().enumerate() {
                let Some((r, projected)) = r else { continue };
                let w = self.point_weights[j] * inv;
                let unit = self.units[i];
                let dx = projected.dq * camera.rotation.matrix() / unit;
                for a in 0..2 {
                    for m in 0..k {
                        identity[m] = dx.row(a).dot(&self.modes[j][m].transpose());
                    }
                    for (t, d) in projected.camera_row(a).iter().enumerate() {
                        own[t] = d / unit;
                    }
                    for (l, d) in self.photo_modes[j].iter().enumerate() {
                        own[CAMERA + l] = dx.row(a).dot(&d.transpose());
                    }
                    h.view_mut((0, 0), (k, k)).ger(w, &identity, &identity, 1.0);
                    h.view_mut((0, base), (k, width)).ger(w, &identity, &own, 1.0);
                    h.view_mut((base, 0), (width, k)).ger(w, &own, &identity, 1.0);
                    h.view_mut((base, base), (width, width)).ger(w, &own, &own, 1.0);
                    g.rows_mut(0, k).axpy(w * r[a], &identity, 1.0);
                    g.rows_mut(base, width).axpy(w * r[a], &own, 1.0);
                }
            }
        }
    }
}

impl FaceSpace {
    /// Refines a landmark fit ([`FaceSpace::fit_photos`]) with the photos' pixels: see the
    /// [module documentation](self). `views` are the photos the landmark fit was given, in its
    /// order; `reference` the reference the space belongs to (its face region is where the
    /// surface is sampled).
    ///
    /// # Errors
    /// [`FaceError::Option`] when the views do not match the fit, or for options out of range
    /// (levels not 1 to 6, field levels 0; the eye pixels, spacing, `σ`, `β`, `ε`, window or
    /// the field's deviations not positive and finite).
    pub fn refine_photos(
        &self,
        reference: &ReferenceFace,
        fit: &PhotoSpaceFit,
        views: &[RefineView<'_>],
        point_weights: &[Real; POINT_COUNT],
        options: &RefineOptions,
    ) -> Result<Refinement, FaceError> {
        check_refine(fit, views, options)?;
        let problem = self.problem(fit, views, point_weights, options);
        let (state, iterations, level) =
            self.run_levels(reference, &problem, options, None, options.hold_face)?;
        let landmarks = &problem.landmarks;
        // The landmark fit as it stands: its own cameras, scaled orthographic (the
        // optimisation starts from them with a typical perspective).
        let mut start = problem.start.clone();
        start.cameras.iter_mut().for_each(|c| c.perspective = 0.0);
        let mut after_visibility = level.visibility(&state);
        let mut after = level.disagreement(&state, &after_visibility);
        // Over the face: the weighted RMS over every sample two photos see, and their count.
        let overall = |per: &[Option<(Real, Real)>]| {
            let (sum, total, count) = per
                .iter()
                .flatten()
                .fold((0.0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + 1));
            ((sum / total.max(1e-12)).sqrt(), count)
        };
        // Per sample: the weighted RMS, NaN where fewer than two photos see it.
        let rms = |per: &[Option<(Real, Real)>]| -> Vec<Real> {
            per.iter()
                .map(|p| p.map_or(Real::NAN, |(sum, total)| (sum / total).sqrt()))
                .collect()
        };
        // The landmark fit's face is judged with whichever of its cameras (orthographic, or the
        // refinement's start) the photos agree on better.
        let before = [&start, &problem.start]
            .into_iter()
            .map(|s| level.disagreement(s, &level.visibility(s)))
            .min_by(|a, b| overall(a).0.total_cmp(&overall(b).0))
            .expect("two candidates");
        let ((before_rms, _), (after_rms, seen_twice)) = (overall(&before), overall(&after));
        let disagreement = (before_rms, after_rms);
        // The check on photos left out costs about as much as the refinement again: it runs
        // only where the refinement would be kept without it.
        let held_out = if options.held_out && fall(disagreement) >= options.min_gain {
            self.held_out_check(reference, &problem, options)?
        } else {
            None
        };
        let landmark_rms = (landmarks.rms(&start), landmarks.rms(&state));
        let (accepted, mut note) = verdict(disagreement, landmark_rms, held_out, options);
        let share = if accepted {
            kept_share(fall(disagreement), options)
        } else {
            0.0
        };
        let kept = if share >= 1.0 {
            state
        } else if accepted {
            // Part of the way: the face blended; the refined cameras kept. (Aligning them
            // anew to the photos on the blended face, the face held, cost 150 ms for eight
            // photos of the scan, 16 iterations at the finest level, and left the photos'
            // disagreement on it at 0.388 against 0.386 before: the landmarks pull the
            // cameras as much as the pixels do, and the refined cameras already fit.)
            let blend = |a: Real, b: Real| a + share * (b - a);
            let field = if state.field.is_empty() {
                Vec::new()
            } else {
                let zero = std::iter::repeat(0.0);
                let from = start.field.iter().copied().chain(zero);
                from.zip(&state.field).map(|(a, &b)| blend(a, b)).collect()
            };
            let blended = State {
                weights: start
                    .weights
                    .iter()
                    .zip(&state.weights)
                    .map(|(&a, &b)| blend(a, b))
                    .collect(),
                cameras: state.cameras,
                shifts: start
                    .shifts
                    .iter()
                    .zip(&state.shifts)
                    .map(|(a, b)| a.iter().zip(b).map(|(&a, &b)| blend(a, b)).collect())
                    .collect(),
                field,
            };
            after_visibility = level.visibility(&blended);
            after = level.disagreement(&blended, &after_visibility);
            note.push_str(&format!(
                "; kept {:.0}% of the way from the landmark fit (a fall of {:.1}%, whole from {:.1}%)",
                100.0 * share,
                100.0 * fall(disagreement),
                100.0 * options.full_gain
            ));
            blended
        } else {
            start
        };
        let (width, height, before) = level.grid_of(&rms(&before));
        let (_, _, after) = level.grid_of(&rms(&after));
        let map = ConsistencyMap {
            width,
            height,
            before,
            after,
        };
        let coverage = after_visibility
            .iter()
            .map(|v| v.iter().filter(|&&c| c > 0.0).count() as Real / v.len().max(1) as Real)
            .collect();
        let identity = self.sigma().len();
        // The shifts (none unless every photo has the space's expressions), clamped against
        // rounding: their limits keep each weight in [0, 1].
        let mut expressions = fit.expressions.clone();
        for (e, own) in expressions.iter_mut().zip(&kept.shifts) {
            for (&l, shift) in problem.shifted.iter().zip(&kept.weights[identity..]) {
                e[l] = (e[l] + shift).clamp(0.0, 1.0);
            }
            // Each photo's own shifts, likewise kept in [0, 1] by their limits.
            for (&l, shift) in problem.photo_shifted.iter().zip(own) {
                e[l] = (e[l] + shift).clamp(0.0, 1.0);
            }
        }
        let mut weights = kept.weights;
        weights.truncate(identity);
        Ok(Refinement {
            displacement: kept.field.iter().map(|&d| Vector3::new(0.0, 0.0, d)).collect(),
            weights,
            expressions,
            cameras: kept.cameras,
            disagreement,
            landmark_rms,
            coverage,
            map,
            samples: (level.samples.len(), seen_twice),
            iterations,
            held_out,
            accepted,
            share,
            note,
        })
    }

    /// [`RefineOptions::held_out`]'s check: per fold, the face refined without its photos
    /// and the landmark fit's face with its cameras refined by the same photos; the held-out
    /// photos' disagreement with the others on each, summed over the folds, as weighted
    /// RMS (landmark fit, refined). `None` for fewer than three photos.
    fn held_out_check(
        &self,
        reference: &ReferenceFace,
        problem: &Problem<'_>,
        options: &RefineOptions,
    ) -> Result<Option<(Real, Real)>, FaceError> {
        let folds = folds(&problem.start.cameras);
        if folds.is_empty() {
            return Ok(None);
        }
        // Every level but the finest: the folds' refinements and their comparison a quarter of
        // the samples each.
        let options = &if options.levels > 1 {
            RefineOptions {
                levels: options.levels - 1,
                eye_pixels: options.eye_pixels / 2.0,
                spacing: options.spacing * 2.0,
                ..*options
            }
        } else {
            *options
        };
        let (mut before, mut after) = ((0.0, 0.0), (0.0, 0.0));
        for held_out in &folds {
            for (face_held, sum) in [(true, &mut before), (false, &mut after)] {
                let (state, _, mut level) =
                    self.run_levels(reference, problem, options, Some(held_out), face_held)?;
                // The photos left out, placed by their landmarks alone so far, are aligned by
                // their pixels to the others with the face and the others' cameras held: each
                // face is judged by how well it can explain them, not by how well their
                // landmarks placed them.
                level.photo_weights.iter_mut().for_each(|w| *w = 1.0);
                level.face_held = true;
                level.cameras_held = held_out.iter().map(|out| !out).collect();
                let state = level.minimise(state, options.iterations, &mut 0);
                let (s, w) = level.held_out_error(&state, held_out);
                sum.0 += s;
                sum.1 += w;
            }
        }
        let rms = |(s, w): (Real, Real)| (s / w.max(1e-12)).sqrt();
        Ok(Some((rms(before), rms(after))))
    }
}

/// The field's prior as stencils over the control points of a `grid` (rows, columns), scaled by
/// the deviations: each point's ridge under [`RefineOptions::field_sigma`], and the thin
/// plate's second differences along rows, columns and across under
/// [`RefineOptions::field_bend`]. A residual is a stencil's weighted sum of the field.
fn field_stencils((rows, cols): (usize, usize), options: &RefineOptions) -> Vec<Vec<(usize, Real)>> {
    let bend = 1.0 / options.field_bend;
    let ridge = 1.0 / options.field_sigma;
    let at = |i: usize, j: usize| i * cols + j;
    let mut out = Vec::new();
    for i in 0..rows {
        for j in 0..cols {
            out.push(vec![(at(i, j), ridge)]);
            if i + 2 < rows {
                out.push(vec![
                    (at(i, j), bend),
                    (at(i + 1, j), -2.0 * bend),
                    (at(i + 2, j), bend),
                ]);
            }
            if j + 2 < cols {
                out.push(vec![
                    (at(i, j), bend),
                    (at(i, j + 1), -2.0 * bend),
                    (at(i, j + 2), bend),
                ]);
            }
            if i + 1 < rows && j + 1 < cols {
                let t = std::f64::consts::SQRT_2 * bend;
                out.push(vec![
                    (at(i, j), t),
                    (at(i + 1, j), -t),
                    (at(i, j + 1), -t),
                    (at(i + 1, j + 1), t),
                ]);
            }
        }
    }
    out
}

/// The half-bandwidth of the field's block of the normal equations: the widest spread of
/// control points that one sample's basis (`basis[s]`) or one of the prior's stencils couples.
fn field_bandwidth(basis: &[Vec<(usize, Real)>], cols: usize) -> usize {
    let spread = |points: &mut dyn Iterator<Item = usize>| {
        let (lo, hi) = points.fold((usize::MAX, 0), |(lo, hi), p| (lo.min(p), hi.max(p)));
        hi.saturating_sub(lo)
    };
    let widest = basis.iter().map(|b| spread(&mut b.iter().map(|&(p, _)| p)));
    // The prior's stencils reach two rows on at most (`field_stencils`; one row and one
    // column is less).
    widest.max().unwrap_or(0).max(2 * cols)
}

/// What every level of a refinement shares: the starting state, the landmarks' problem, each
/// photo's expression as a displacement of the control grid, and the photos' face boxes.
struct Problem<'a> {
    /// The weights after the identity's are the shifts of the expressions [`Problem::shifted`].
    start: State,
    /// The expression modes whose shift the photos share ([`RefineOptions::expression_shift`]).
    shifted: Vec<usize>,
    /// Each weight's prior deviation: the identity's, then each shift's `τ_δ`.
    sigma_prior: Vec<Real>,
    /// Each shift's range: where no photo's weight leaves `[0, 1]`.
    shift_limits: Vec<(Real, Real)>,
    /// The expression modes each photo shifts on its own
    /// ([`RefineOptions::expression_photos`]).
    photo_shifted: Vec<usize>,
    /// Per photo, each own shift's range: where its weight stays in `[0, 1]`.
    photo_shift_limits: Vec<Vec<(Real, Real)>>,
    /// Each photo's `κ` prior centre: its starting camera with [`TYPICAL_FOCAL`].
    perspective_prior: Vec<Real>,
    landmarks: Landmarks<'a>,
    expression_grids: Vec<Vec<Vector3<Real>>>,
    boxes: Vec<[Real; 4]>,
}

impl FaceSpace {
    /// The shared parts of a refinement of `fit` by `views`.
    fn problem<'a>(
        &self,
        fit: &PhotoSpaceFit,
        views: &'a [RefineView<'a>],
        point_weights: &'a [Real; POINT_COUNT],
        options: &RefineOptions,
    ) -> Problem<'a> {
        // Each photo's expression (held at the landmark fit's, or shifted by the photos'
        // shared shift) as displacements of the control grid and of the structure; none when
        // the fit had no expressions.
        let expressions: &[Vec<Real>] = if fit
            .expressions
            .iter()
            .all(|e| e.len() == self.expressions().len())
        {
            &fit.expressions
        } else {
            &[]
        };
        let shifted = match options.expression_shift {
            Some(_) if !expressions.is_empty() => shifted_expressions(expressions, SHIFTED_EXPRESSIONS_MAX),
            _ => Vec::new(),
        };
        let photo_shifted = match options.expression_photos {
            Some(_) if !expressions.is_empty() => shifted_expressions(expressions, PHOTO_EXPRESSIONS_MAX),
            _ => Vec::new(),
        };
        let photo_shift_limits = expressions
            .iter()
            .filter(|_| !photo_shifted.is_empty())
            .map(|e| photo_shifted.iter().map(|&l| (-e[l], 1.0 - e[l])).collect())
            .collect();
        let shift_limits = shifted
            .iter()
            .map(|&l| {
                let (low, high) = expressions
                    .iter()
                    .fold((Real::INFINITY, Real::NEG_INFINITY), |(lo, hi), e| {
                        (lo.min(e[l]), hi.max(e[l]))
                    });
                (-low, 1.0 - high)
            })
            .collect();
        let tau = options.expression_shift.unwrap_or(1.0);
        let sigma_prior = self
            .sigma()
            .iter()
            .copied()
            .chain(shifted.iter().map(|_| tau))
            .collect();
        let start = State {
            weights: fit
                .weights
                .iter()
                .copied()
                .chain(shifted.iter().map(|_| 0.0))
                .collect(),
            cameras: fit
                .poses
                .iter()
                .zip(views)
                .map(|((pose, offset), view)| {
                    let mut camera = RefinedCamera::orthographic(
                        pose,
                        *offset,
                        (view.image.width() as u32, view.image.height() as u32),
                    );
                    if options.perspective {
                        camera.perspective = typical_perspective(&camera, view.image);
                    }
                    camera
                })
                .collect(),
            shifts: vec![vec![0.0; photo_shifted.len()]; fit.poses.len()],
            field: if options.field {
                vec![0.0; self.surfaces().base().rows() * self.surfaces().base().cols()]
            } else {
                Vec::new()
            },
        };
        let displacement = |modes: &[Vec<Vector3<Real>>], len: usize| -> Vec<Vec<Vector3<Real>>> {
            expressions
                .iter()
                .map(|e| {
                    let mut d = vec![Vector3::zeros(); len];
                    add_weighted(&mut d, modes, e);
                    d
                })
                .collect()
        };
        let base = self.surfaces().base();
        let expression_grids = displacement(&self.expressions().grid, base.rows() * base.cols());
        let structure = self.structure_samples();
        let landmarks = Landmarks {
            base: structure.base.clone(),
            modes: (0..POINT_COUNT)
                .map(|j| {
                    let identity = structure.modes.iter().map(|m| m[j]);
                    let shifts = shifted.iter().map(|&l| self.expressions().structure[l][j]);
                    identity.chain(shifts).collect()
                })
                .collect(),
            expression: displacement(&self.expressions().structure, POINT_COUNT),
            photo_modes: (0..POINT_COUNT)
                .map(|j| {
                    photo_shifted
                        .iter()
                        .map(|&l| self.expressions().structure[l][j])
                        .collect()
                })
                .collect(),
            views,
            point_weights,
            units: start.cameras.iter().map(|c| c.scale).collect(),
        };
        Problem {
            perspective_prior: start.cameras.iter().map(|c| c.perspective).collect(),
            start,
            shifted,
            sigma_prior,
            shift_limits,
            photo_shifted,
            photo_shift_limits,
            landmarks,
            expression_grids,
            boxes: face_boxes(views),
        }
    }

    /// Level `level_index`'s surface samples ([`Samples::new`]): they depend on the level and
    /// the problem, not on the state.
    fn level_samples(
        &self,
        reference: &ReferenceFace,
        problem: &Problem<'_>,
        level_index: usize,
        options: &RefineOptions,
    ) -> Result<Samples, FaceError> {
        let spacing = options.spacing * coarseness(options, level_index);
        let grids = |modes: &[usize]| -> Vec<&[Vector3<Real>]> {
            modes
                .iter()
                .map(|&l| self.expressions().grid[l].as_slice())
                .collect()
        };
        Samples::new(
            self,
            reference,
            &problem.expression_grids,
            &grids(&problem.shifted),
            &grids(&problem.photo_shifted),
            spacing,
            options.window_eyes,
            match options.window {
                Window::Lit if options.expression_normals => Partials::WithExpressions,
                Window::Lit => Partials::Identity,
                _ => Partials::None,
            },
        )
    }

    /// Level `level_index` of `options.levels` (the last is the finest), its photos resampled
    /// about their faces as the cameras of `state` see them; its samples made here, or given
    /// when they were made already ([`FaceSpace::level_samples`]).
    fn level<'a>(
        &'a self,
        reference: &ReferenceFace,
        problem: &'a Problem<'a>,
        state: &State,
        (level_index, samples): (usize, Option<Samples>),
        options: &'a RefineOptions,
    ) -> Result<Level<'a>, FaceError> {
        let eye_pixels = options.eye_pixels / coarseness(options, level_index);
        let images = || -> Vec<LevelImage> {
            problem
                .landmarks
                .views
                .par_iter()
                .zip(&problem.boxes)
                .zip(&state.cameras)
                .map(|((v, b), camera)| {
                    let eye = 50.0 * camera.scale;
                    let factor = (eye_pixels / eye).min(1.0);
                    let window =
                        (options.window == Window::Image).then_some(options.window_eyes * eye * factor);
                    LevelImage::new(v.image, *b, factor, window, options.window == Window::Lit)
                })
                .collect()
        };
        // The photos' crops side by side, and beside the samples: each crop alone is too small
        // to keep both cores busy.
        let (images, samples) = match samples {
            Some(samples) => (images(), samples),
            None => {
                let (images, samples) = rayon::join(images, || {
                    self.level_samples(reference, problem, level_index, options)
                });
                (images, samples?)
            }
        };
        let grid = (self.surfaces().base().rows(), self.surfaces().base().cols());
        let (field_stencils, field_bandwidth) = if state.field.is_empty() {
            (Vec::new(), 0)
        } else {
            (
                field_stencils(grid, options),
                field_bandwidth(&samples.basis, grid.1),
            )
        };
        let mut level = Level {
            images,
            samples,
            landmarks: &problem.landmarks,
            sigma_prior: &problem.sigma_prior,
            shift_limits: &problem.shift_limits,
            photo_shift_limits: &problem.photo_shift_limits,
            perspective_prior: &problem.perspective_prior,
            options,
            field_stencils,
            field_bandwidth,
            photo_weights: vec![1.0; problem.start.cameras.len()],
            face_held: false,
            cameras_held: Vec::new(),
        };
        if options.photo_weights {
            level.photo_weights = level.photo_weights(state);
        }
        Ok(level)
    }

    /// Every level, coarse to fine, from the problem's start: the refined state, the
    /// iterations run and the finest level.
    /// Photos marked in `held_out` count for nothing but their landmarks; with `face_held`
    /// only the cameras move.
    ///
    /// The finest level's samples are made while the coarser levels run: those levels are
    /// small, and keep two cores only partly busy (eight photos of `lps-head`: the finest
    /// level's samples take 29 ms, the coarser levels about 35).
    fn run_levels<'a>(
        &'a self,
        reference: &ReferenceFace,
        problem: &'a Problem<'a>,
        options: &'a RefineOptions,
        held_out: Option<&[bool]>,
        face_held: bool,
    ) -> Result<(State, usize, Level<'a>), FaceError> {
        let finest = options.levels - 1;
        // The field joins at the finest `field_levels` levels, from zero.
        let field_from = options.levels.saturating_sub(options.field_levels);
        let run = |state: State, level_index: usize, samples: Option<Samples>, iterations: &mut usize| {
            let mut level = self.level(reference, problem, &state, (level_index, samples), options)?;
            if let Some(held_out) = held_out {
                for (w, &out) in level.photo_weights.iter_mut().zip(held_out) {
                    if out {
                        *w = 0.0;
                    }
                }
            }
            level.face_held = face_held;
            let state = level.minimise(state, options.iterations, iterations);
            Ok::<_, FaceError>((state, level))
        };
        let join_field = |state: &mut State, field: &mut Vec<Real>, level_index: usize| {
            if level_index == field_from {
                state.field = std::mem::take(field);
            }
        };
        let (finest_samples, coarse) = rayon::join(
            || self.level_samples(reference, problem, finest, options),
            || -> Result<_, FaceError> {
                let mut state = problem.start.clone();
                let mut field = std::mem::take(&mut state.field);
                let mut iterations = 0;
                for level_index in 0..finest {
                    join_field(&mut state, &mut field, level_index);
                    state = run(state, level_index, None, &mut iterations)?.0;
                }
                Ok((state, field, iterations))
            },
        );
        let (mut state, mut field, mut iterations) = coarse?;
        join_field(&mut state, &mut field, finest);
        let (state, level) = run(state, finest, Some(finest_samples?), &mut iterations)?;
        Ok((state, iterations, level))
    }
}

/// How much coarser level `level_index` of `options.levels` is than the finest: `2ᵏ` for the
/// `k`-th level above it (its samples that much further apart, its eyes that many times fewer
/// pixels apart).
fn coarseness(options: &RefineOptions, level_index: usize) -> Real {
    2.0_f64.powi((options.levels - 1 - level_index) as i32)
}

/// [`FaceSpace::refine_photos`]' checks: one view per photo of the fit with 40 points, 1 to 6
/// levels, the field at one level or more, positive and finite scales and weights.
fn check_refine(
    fit: &PhotoSpaceFit,
    views: &[RefineView<'_>],
    options: &RefineOptions,
) -> Result<(), FaceError> {
    if views.len() != fit.poses.len() || views.iter().any(|v| v.points.len() != POINT_COUNT) {
        return FaceError::option("views", views.len(), "one per photo of the fit, 40 points each");
    }
    let positive = |v: Real| v > 0.0 && v.is_finite();
    if !(1..=6).contains(&options.levels) {
        return FaceError::option("levels", options.levels, "1 to 6");
    }
    if options.field_levels == 0 {
        return FaceError::option("field levels", "0", "at least 1");
    }
    for (name, v) in [
        ("eye pixels", options.eye_pixels),
        ("spacing", options.spacing),
        ("sigma", options.sigma),
        ("beta", options.beta),
        ("noise", options.noise),
        ("window eyes", options.window_eyes),
        ("field bend", options.field_bend),
        ("field sigma", options.field_sigma),
    ] {
        if !positive(v) {
            return FaceError::option(name, v, "positive and finite");
        }
    }
    for (name, v) in [
        ("expression shift", options.expression_shift),
        ("expression photos", options.expression_photos),
    ] {
        if let Some(v) = v.filter(|&v| !positive(v)) {
            return FaceError::option(name, v, "positive and finite, or none");
        }
    }
    for (name, v) in [("min gain", options.min_gain), ("full gain", options.full_gain)] {
        if v.is_nan() {
            return FaceError::option(name, v, "a number (infinite allowed)");
        }
    }
    Ok(())
}

/// Each photo's face box `[x0, y0, x1, y1]`, pixels: its landmarks' box grown by three
/// quarters of its size (the forehead and cheeks lie beyond the points), clamped to the image.
fn face_boxes(views: &[RefineView<'_>]) -> Vec<[Real; 4]> {
    views
        .iter()
        .map(|v| {
            let (mut x0, mut y0, mut x1, mut y1) = (Real::MAX, Real::MAX, Real::MIN, Real::MIN);
            for p in v.points {
                (x0, x1) = (x0.min(p.x), x1.max(p.x));
                (y0, y1) = (y0.min(-p.y), y1.max(-p.y));
            }
            let (mx, my) = (0.75 * (x1 - x0), 0.75 * (y1 - y0));
            [
                (x0 - mx).max(0.0),
                (y0 - my).max(0.0),
                (x1 + mx).min(v.image.width() as Real - 1.0),
                (y1 + my).min(v.image.height() as Real - 1.0),
            ]
        })
        .collect()
}

impl Level<'_> {
    /// Damped Gauss-Newton (Levenberg-Marquardt on the diagonal) from `state` on this level,
    /// `max_iterations` at most, each counted in `iterations`; stops when a step improves the
    /// cost by less than [`MIN_RELATIVE_GAIN`] of it or no damping finds a better state.
    ///
    /// Eight dampings are tried per iteration, each ten times the last, but the cost is not
    /// taken for a step that cannot help: one the model says lowers the cost by less than
    /// [`MIN_PREDICTED_FALL`] of it (the search stops), or
    /// one [`SAME_STEP`]-close to a step that just failed. The equations hold each photo's
    /// normalisation while the cost re-fits it at every state, so near a level's end their
    /// steps raise the cost whatever the damping; and from a small damping, ten times more
    /// barely changes the step (in the traces, the damping began to matter from about 10⁻²). Traced
    /// over 26 finest levels (`photo_eval --ict-subjects 5 --seeds 1 --counts 2,4`), 51 of
    /// the 345 steps tried were within 2% of the failed step before them in the model's
    /// fall ([`Equations::predicted_fall`]), and 13 promised less than 10⁻⁶ of the cost.
    ///
    /// Two changes to the search were measured and dropped (`photo_eval`, the 105 sets; mean
    /// ratio to the mean face, sets more than 2% worse than the landmark fit, the widest pair
    /// of halves of 16 photos; the default 0.694, 4, 0.70 mm). Trial states costed with the
    /// lights and gains held at the current state's, as the equations hold them (one
    /// objective per iteration, the normalisation re-fitted only after a step is taken):
    /// 0.700, 7, 0.99 mm, the scan's `photos-8` 0.89 against 0.83. The Cauchy scale 9, 3 and 1
    /// times `2σ` over the three levels (graduated non-convexity): 0.698, 4. Neither made
    /// the refinement less sensitive where a photo conflicts with the others: with an
    /// inverted fourth photo (`tests/splineface/refine.rs`), scaling one image by `1 + 10⁻⁶`
    /// moves the refined face by up to 0.15 units (less than 10⁻⁴ with consistent photos).
    fn minimise(&self, mut state: State, max_iterations: usize, iterations: &mut usize) -> State {
        let mut damping = 1e-3;
        for _ in 0..max_iterations {
            *iterations += 1;
            let visibility = self.visibility(&state);
            let (equations, cost) = self.normal_equations(&state, &visibility);
            let mut improved = false;
            // The model's fall for the last step that failed.
            let mut failed: Option<Real> = None;
            for _ in 0..8 {
                let Some(step) = equations.solve_damped(damping) else {
                    damping *= 10.0;
                    continue;
                };
                let fall = equations.predicted_fall(&step, damping);
                if fall.is_nan() || fall < MIN_PREDICTED_FALL * cost {
                    break;
                }
                if failed.is_some_and(|last| last - fall < SAME_STEP * last) {
                    failed = Some(fall);
                    damping *= 10.0;
                    continue;
                }
                let step = -step;
                let mut next = state.moved(&step);
                let identity = next.weights.len() - self.shift_limits.len();
                for (w, &(low, high)) in next.weights[identity..].iter_mut().zip(self.shift_limits) {
                    *w = w.clamp(low, high);
                }
                for (shifts, limits) in next.shifts.iter_mut().zip(self.photo_shift_limits) {
                    for (d, &(low, high)) in shifts.iter_mut().zip(limits) {
                        *d = d.clamp(low, high);
                    }
                }
                let next_cost = self.cost(&next, &visibility);
                if next_cost.is_finite() && next_cost < cost {
                    let relative = (cost - next_cost) / cost.max(1e-12);
                    state = next;
                    damping = (damping / 3.0).max(1e-7);
                    improved = relative > MIN_RELATIVE_GAIN;
                    break;
                }
                failed = Some(fall);
                damping *= 10.0;
            }
            if !improved {
                break;
            }
        }
        state
    }
}

/// [`Level::minimise`] stops when a step lowers the cost by less than this share of it.
///
/// 10⁻⁴ (10⁻⁵ before). The finest level of `lps-head/photos-8` gains 8·10⁻², 1.6·10⁻²,
/// 7.7·10⁻³, 2.3·10⁻³, 9.7·10⁻⁵, 1.1·10⁻⁴ and 1.8·10⁻⁷ of its cost in its seven iterations
/// at 10⁻⁵, and stops after the fifth at 10⁻⁴. Measured by `photo_eval --methods default
/// --baseline tools/results/photos.md` (the 105 sets; the former tolerance's figures in
/// brackets): mean ratio to the mean face 0.695 (0.694), to the landmark fit 0.775 (0.773),
/// 4 sets more than 2% worse than it (the same four), 7 sets better and 8 worse than before by
/// more than 0.005; `photos-8` 0.83 and `photos-3` 0.78 (the same), the widest pair of halves
/// 0.70 mm (the same). `tools/ab-bench` on `photos-8` (5 runs by turns): the refinement 476
/// → 388 ms best, 507 → 402 median, the whole run 1.09 → 0.99 s best, 1.13 → 1.01 median.
const MIN_RELATIVE_GAIN: Real = 1e-4;

/// [`Level::minimise`] does not take the cost of a step the model says lowers it by less
/// than this share (the search stops there).
const MIN_PREDICTED_FALL: Real = 1e-6;

/// A step whose predicted fall is within this share of a step that just failed is not tried
/// ([`Level::minimise`]).
const SAME_STEP: Real = 0.02;

/// One sample's robust consistency cost before its scale `β / σ²`: the Cauchy loss (`c = 2σ`)
/// of each view's normalised intensity about the views' weighted mean, weighted.
fn sample_cost(seen: &[Seen], mean: Real, c: Real) -> Real {
    seen.iter()
        .map(|v| v.weight * c * c * (1.0 + ((v.value - mean) / c).powi(2)).ln())
        .sum::<Real>()
}

/// The relative fall of a disagreement `(before, after)`.
fn fall((before, after): (Real, Real)) -> Real {
    1.0 - after / before
}

/// How much of the way from the landmark fit to the refined face is kept for a fall `gain` of
/// the disagreement, once the refinement is accepted: all of it from
/// [`RefineOptions::full_gain`] on, in proportion between [`RefineOptions::min_gain`] and it.
fn kept_share(gain: Real, options: &RefineOptions) -> Real {
    let (low, high) = (options.min_gain, options.full_gain);
    if gain >= high || !(low.is_finite() && high > low) {
        1.0
    } else {
        ((gain - low) / (high - low)).clamp(0.0, 1.0)
    }
}

/// Whether the refined face is kept, and why: the photos must agree better by
/// [`RefineOptions::min_gain`] and the landmarks stay within [`RefineOptions::landmark_slack`].
fn verdict(
    disagreement: (Real, Real),
    landmark_rms: (Real, Real),
    held_out: Option<(Real, Real)>,
    options: &RefineOptions,
) -> (bool, String) {
    let gain = fall(disagreement);
    // A NaN gain (no photo pair saw the face) keeps the landmark fit too.
    if gain.is_nan() || gain < options.min_gain {
        (
            false,
            format!(
                "the photos agree no better on the refined face (disagreement {:.3} → {:.3}): the landmark fit stands",
                disagreement.0, disagreement.1
            ),
        )
    } else if let Some((b, a)) = held_out
        && fall((b, a)) < options.min_held_out_gain
    {
        (
            false,
            format!(
                "the photos left out agree no better with the others on the face the others refined (disagreement {b:.3} → {a:.3}): the landmark fit stands"
            ),
        )
    } else if landmark_rms.1 > landmark_rms.0 + options.landmark_slack {
        (
            false,
            format!(
                "the refined face moved off the landmarks (RMS {:.2} → {:.2} units): the landmark fit stands",
                landmark_rms.0, landmark_rms.1
            ),
        )
    } else {
        (
            true,
            format!(
                "refined by the photos' agreement: disagreement {:.3} → {:.3}{}, landmark RMS {:.2} → {:.2} units",
                disagreement.0,
                disagreement.1,
                held_out.map_or(String::new(), |(b, a)| format!(
                    " (photos left out {b:.3} → {a:.3})"
                )),
                landmark_rms.0,
                landmark_rms.1
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The share kept rises linearly from `min_gain` to `full_gain`, and is a step where the
    /// ramp is empty or has no finite start.
    #[test]
    fn the_share_kept_follows_the_fall_between_the_thresholds() {
        let options = |min_gain, full_gain| RefineOptions {
            min_gain,
            full_gain,
            ..RefineOptions::default()
        };
        let ramp = options(0.1, 0.2);
        for (gain, share) in [(0.1, 0.0), (0.125, 0.25), (0.15, 0.5), (0.2, 1.0), (0.7, 1.0)] {
            assert!(
                (kept_share(gain, &ramp) - share).abs() < 1e-12,
                "{gain}: {}",
                kept_share(gain, &ramp)
            );
        }
        // A step (whole once accepted, at `min_gain` or above): a ramp of no width, upside
        // down, or from minus infinity.
        for step in [
            options(0.15, 0.15),
            options(0.15, 0.1),
            options(Real::NEG_INFINITY, 0.2),
        ] {
            for gain in [0.15, 0.17, 0.5] {
                assert_eq!(kept_share(gain, &step), 1.0);
            }
        }
    }

    /// One sample's normal equations by their closed-form blocks against the definition:
    /// every view's full residual row (the identity through the modes, every seeing view's
    /// camera, the field) and the sum of their outer products, with the views' photos not
    /// consecutive and the field's control points out of order; for the point alone and for
    /// the point and the normal ([`Window::Lit`]).
    /// Each photo's block is its camera's alone, or widened by its own expression shifts
    /// ([`RefineOptions::expression_photos`]; the views' derivatives beyond the block's width
    /// must be ignored).
    #[test]
    fn sample_blocks_equal_the_rows_gram_matrix() {
        for width in [CAMERA, CAMERA + 2, PHOTO_MAX] {
            sample_blocks::<3>(width);
            sample_blocks::<6>(width);
        }
    }

    fn sample_blocks<const D: usize>(width: usize) {
        let value = |i: usize| ((i * 7919 + 13) % 1009) as Real / 1009.0 - 0.5;
        let k = 5;
        let photos = 4;
        let field = k + width * photos;
        let n = field + 6;
        let modes: Vec<SVector<Real, D>> = (0..k)
            .map(|m| SVector::from_fn(|r, _| value(D * m + r)))
            .collect();
        let basis = [(1, 0.3), (4, 0.5), (2, 0.2)];
        let seen: Vec<Seen> = [0, 2, 3]
            .iter()
            .enumerate()
            .map(|(x, &photo)| Seen {
                photo,
                weight: 0.4 + 0.2 * x as Real,
                value: value(100 + x),
                d_point: Vector3::new(value(200 + x), value(300 + x), value(400 + x)),
                d_normal: Vector3::new(value(600 + x), value(700 + x), value(800 + x)),
                d_photo: std::array::from_fn(|t| value(500 + 20 * x + t)),
            })
            .collect();
        let (total, mean) = agreement(&seen).expect("three views");
        let (scale, c) = (0.7, 1.1);
        let mut equations = Equations::zeros(field, n - field, 3);
        Level::add_sample(
            &modes,
            width,
            (&basis, &seen, (total, mean), (scale, c)),
            &mut equations,
        );
        let (h, g) = (equations.to_dense(), equations.g);

        let mut expected_h = DMatrix::<Real>::zeros(n, n);
        let mut expected_g = DVector::<Real>::zeros(n);
        // The view's derivative in the sample's point (and normal), written out.
        let jet_of = |v: &Seen| -> SVector<Real, D> {
            let all = [
                v.d_point.x,
                v.d_point.y,
                v.d_point.z,
                v.d_normal.x,
                v.d_normal.y,
                v.d_normal.z,
            ];
            SVector::from_fn(|r, _| all[r])
        };
        let mean_point: SVector<Real, D> = seen.iter().map(|v| jet_of(v) * (v.weight / total)).sum();
        for (at, v) in seen.iter().enumerate() {
            let r = v.value - mean;
            let root = (scale * v.weight * cauchy(r, c)).sqrt();
            let q = jet_of(v) - mean_point;
            let mut row = DVector::<Real>::zeros(n);
            for (m, mode) in modes.iter().enumerate() {
                row[m] = root * q.dot(mode);
            }
            for (b, u) in seen.iter().enumerate() {
                for t in 0..width {
                    let own = if b == at { v.d_photo[t] } else { 0.0 };
                    row[k + width * u.photo + t] = root * (own - u.weight / total * u.d_photo[t]);
                }
            }
            for &(cp, beta) in &basis {
                row[field + cp] = root * q[2] * beta;
            }
            expected_h += &row * row.transpose();
            expected_g += &row * (root * r);
        }
        for j in 0..n {
            for i in 0..=j {
                assert!(
                    (h[(i, j)] - expected_h[(i, j)]).abs() < 1e-12,
                    "H({i}, {j}): {} against {}",
                    h[(i, j)],
                    expected_h[(i, j)]
                );
            }
            for i in j + 1..field {
                assert_eq!(h[(i, j)], 0.0, "only the dense block's upper triangle is filled");
            }
        }
        assert!((g - expected_g).amax() < 1e-12);
    }

    /// The shape's own normals and their derivatives in the identity weights
    /// ([`Samples::shape_normals`]) against central differences of the normals themselves,
    /// away from the mean face (every mode's weight non-zero); the normals are the base
    /// surface's at zero weights.
    #[test]
    fn shape_normals_follow_the_weights() {
        let reference = ReferenceFace::embedded().as_seen_in_photos().into_owned();
        let space = reference
            .face_space()
            .expect("the embedded reference has a face space");
        let samples = Samples::new(
            &space,
            &reference,
            &[],
            &[],
            &[],
            12.0,
            NORMALISATION_EYES,
            Partials::WithExpressions,
        )
        .unwrap();
        let k = space.mode_count();
        let state = |weights: Vec<Real>| State {
            weights,
            cameras: Vec::new(),
            shifts: Vec::new(),
            field: Vec::new(),
        };
        let at_zero = samples.shape_normals(&state(vec![0.0; k]), true).identity;
        for ((n, _), mean) in at_zero.iter().zip(&samples.normals) {
            assert!((n - mean).norm() < 1e-9, "{n} against {mean}");
        }
        let weights: Vec<Real> = space
            .sigma()
            .iter()
            .enumerate()
            .map(|(m, s)| s * [0.8, -1.1, 0.5][m % 3])
            .collect();
        let normals = samples.shape_normals(&state(weights.clone()), true).identity;
        let h = 1e-4;
        let mut worst: Real = 0.0;
        for m in [0, 1, 7, k - 1] {
            let step = |d: Real| {
                let mut w = weights.clone();
                w[m] += d * space.sigma()[m];
                samples.shape_normals(&state(w), true).identity
            };
            let (up, down) = (step(h), step(-h));
            for (s, (n, derivatives)) in normals.iter().enumerate() {
                assert!((n.norm() - 1.0).abs() < 1e-12);
                let numeric = (up[s].0 - down[s].0) / (2.0 * h * space.sigma()[m]);
                let scale = derivatives[m].norm().max(1e-3);
                worst = worst.max((derivatives[m] - numeric).norm() / scale);
            }
        }
        assert!(worst < 1e-5, "relative error of the derivatives {worst:e}");

        // A photo whose expression is mode 3's displacement (one deviation) and another's
        // that is nothing: their normals are the identity surface's with mode 3 moved by one
        // deviation, and the identity surface's.
        let sigma = space.sigma()[3];
        let expressions = [
            space.surfaces().modes()[3].iter().map(|d| d * sigma).collect(),
            vec![Vector3::zeros(); space.surfaces().modes()[3].len()],
        ];
        let with = Samples::new(
            &space,
            &reference,
            &expressions,
            &[],
            &[],
            12.0,
            NORMALISATION_EYES,
            Partials::WithExpressions,
        )
        .unwrap();
        let shaped = with.shape_normals(&state(weights.clone()), true);
        assert_eq!(shaped.photos.len(), 2);
        let mut moved = weights.clone();
        moved[3] += sigma;
        let expected = samples.shape_normals(&state(moved), true).identity;
        for s in 0..samples.len() {
            assert!((shaped.photos[0][s] - expected[s].0).norm() < 1e-9);
            assert!((shaped.photos[1][s] - normals[s].0).norm() < 1e-9);
            assert!((shaped.identity[s].0 - normals[s].0).norm() < 1e-12);
        }
        assert!(
            (0..samples.len()).any(|s| (expected[s].0 - normals[s].0).norm() > 1e-3),
            "the expression turns some normals"
        );

        // A shifted mode that is mode 3's displacement: a weight on it moves the samples and
        // their normals as the same weight on mode 3 does.
        let shifted = Samples::new(
            &space,
            &reference,
            &[],
            &[&space.surfaces().modes()[3]],
            &[],
            12.0,
            NORMALISATION_EYES,
            Partials::Identity,
        )
        .unwrap();
        let mut extended = weights.clone();
        extended.push(sigma);
        let mut moved = weights.clone();
        moved[3] += sigma;
        let (a, b) = (
            shifted.placed(&state(extended.clone())),
            samples.placed(&state(moved.clone())),
        );
        let (na, nb) = (
            shifted.shape_normals(&state(extended), true).identity,
            samples.shape_normals(&state(moved), true).identity,
        );
        for s in 0..samples.len() {
            assert!((a[s].0 - b[s].0).norm() < 1e-9);
            assert!((na[s].0 - nb[s].0).norm() < 1e-9);
            assert!((na[s].1[k] - nb[s].1[3]).norm() < 1e-9);
        }

        // A photo's own shift of a mode that is mode 3's displacement
        // ([`RefineOptions::expression_photos`]): that photo's points and normals are those
        // of mode 3 moved by the shift; the other photo's and the identity's stay.
        let zero = vec![Vector3::zeros(); space.surfaces().modes()[3].len()];
        let own = Samples::new(
            &space,
            &reference,
            &[zero.clone(), zero],
            &[],
            &[&space.surfaces().modes()[3]],
            12.0,
            NORMALISATION_EYES,
            Partials::WithExpressions,
        )
        .unwrap();
        let shifted_state = State {
            shifts: vec![vec![sigma], vec![0.0]],
            ..state(weights.clone())
        };
        let placed = own.placed(&shifted_state);
        let shaped = own.shape_normals(&shifted_state, true);
        for s in 0..samples.len() {
            assert!((own.point(&placed, &shifted_state, s, 0) - b[s].0).norm() < 1e-9);
            assert!((own.point(&placed, &shifted_state, s, 1) - placed[s].0).norm() < 1e-12);
            assert!((shaped.photos[0][s] - nb[s].0).norm() < 1e-9);
            assert!((shaped.photos[1][s] - normals[s].0).norm() < 1e-9);
            assert!((shaped.identity[s].0 - normals[s].0).norm() < 1e-12);
        }
    }

    /// The shifted expressions are those strong enough on average, the strongest first when
    /// there are too many, returned in the modes' order.
    #[test]
    fn shifted_expressions_are_the_strong_ones() {
        let photos = [vec![0.0, 0.2, 0.04, 0.5], vec![0.0, 0.0, 0.08, 0.7]];
        assert_eq!(
            shifted_expressions(&photos, SHIFTED_EXPRESSIONS_MAX),
            vec![1, 2, 3]
        );
        assert_eq!(shifted_expressions(&photos, 2), vec![1, 3]);
        let many: Vec<Vec<Real>> = vec![(0..20).map(|l| 0.1 + l as Real * 0.01).collect()];
        let chosen = shifted_expressions(&many, SHIFTED_EXPRESSIONS_MAX);
        assert_eq!(chosen, (20 - SHIFTED_EXPRESSIONS_MAX..20).collect::<Vec<_>>());
        assert!(shifted_expressions(&[], SHIFTED_EXPRESSIONS_MAX).is_empty());
    }

    /// The folds deal the photos out in order of yaw: every fold holds out photos from both
    /// sides, each photo is held out exactly once, and three photos are left out one at a
    /// time; two have no folds.
    #[test]
    fn folds_deal_the_photos_out_by_yaw() {
        let camera = |yaw_degrees: Real| RefinedCamera {
            rotation: Rotation3::from_axis_angle(&Vector3::y_axis(), yaw_degrees.to_radians()),
            scale: 1.0,
            offset: Vector2::zeros(),
            perspective: 0.0,
            centre: Vector2::zeros(),
        };
        let cameras: Vec<RefinedCamera> = [30.0, -10.0, 5.0, -40.0, 20.0, -25.0].map(camera).into();
        let six = folds(&cameras);
        assert_eq!(six.len(), 2);
        // By yaw: -40 (3), -25 (5), -10 (1), 5 (2), 20 (4), 30 (0); dealt in turn: 3, 1, 4
        // and 5, 2, 0 (either way round).
        let held = |f: &[bool]| (0..f.len()).filter(|&i| f[i]).collect::<Vec<_>>();
        let (a, b) = (held(&six[0]), held(&six[1]));
        assert!(
            (a == [1, 3, 4] && b == [0, 2, 5]) || (a == [0, 2, 5] && b == [1, 3, 4]),
            "{a:?} {b:?}"
        );
        let three = folds(&cameras[..3]);
        assert_eq!(three.len(), 3);
        for i in 0..3 {
            assert_eq!(three.iter().filter(|f| f[i]).count(), 1);
            assert!(three.iter().all(|f| f.iter().filter(|&&h| h).count() == 1));
        }
        assert!(folds(&cameras[..2]).is_empty());
    }

    /// The separable area sampling against its definition, the mean of `k × k` bilinear
    /// samples per crop pixel, with crops reaching past every border of the photo (clamped)
    /// and factors from 1 (one sample) to 1/5.
    #[test]
    fn area_sampling_is_the_mean_of_its_bilinear_samples() {
        let (w, h) = (53, 41);
        let data: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 251) as f32 / 250.0).collect();
        let image = GreyImage::new(w, h, data).unwrap();
        for (origin, factor, size) in [
            (Vector2::new(3.2, 4.7), 1.0, (20, 15)),
            (Vector2::new(-6.5, 10.25), 0.5, (20, 9)),
            (Vector2::new(20.0, -3.0), 0.3, (14, 16)),
            (Vector2::new(-2.0, -2.0), 0.2, (13, 10)),
        ] {
            let crop = area_sample(&image, (origin, factor), size);
            let k = (1.0 / factor).ceil() as usize;
            for r in 0..size.1 {
                for c in 0..size.0 {
                    let mut sum = 0.0;
                    for a in 0..k {
                        for b in 0..k {
                            let x = origin.x + (c as Real + (b as Real + 0.5) / k as Real - 0.5) / factor;
                            let y = origin.y + (r as Real + (a as Real + 0.5) / k as Real - 0.5) / factor;
                            sum += image.sample(image.data(), x, y);
                        }
                    }
                    let want = sum / (k * k) as f32;
                    let got = crop[r * size.0 + c];
                    assert!(
                        (got - want).abs() < 1e-5,
                        "factor {factor}, pixel ({c}, {r}): {got} against {want}"
                    );
                }
            }
        }
    }

    /// The separable blur against the Gaussian's definition: every output pixel the
    /// normalised two-dimensional kernel's weighted sum of the input, borders clamped
    /// (odd sizes, a kernel wider than the image, and a one-pixel image included).
    #[test]
    fn blur_is_the_clamped_gaussian_sum() {
        for (width, height, sigma) in [(37, 23, 1.3), (9, 14, 4.0), (1, 1, 2.0), (64, 3, 0.7)] {
            let values: Vec<f32> = (0..width * height)
                .map(|i| ((i * 7919) % 257) as f32 / 256.0)
                .collect();
            let radius = (3.0 * sigma as Real).ceil() as isize;
            let weight = |d: isize| (-((d * d) as Real) / (2.0 * sigma * sigma)).exp();
            let total: Real = (-radius..=radius).map(weight).sum();
            let blurred = blur(&values, width, height, sigma);
            for r in 0..height as isize {
                for c in 0..width as isize {
                    let mut sum = 0.0;
                    for dr in -radius..=radius {
                        for dc in -radius..=radius {
                            let rr = (r + dr).clamp(0, height as isize - 1) as usize;
                            let cc = (c + dc).clamp(0, width as isize - 1) as usize;
                            sum += weight(dr) * weight(dc) * Real::from(values[rr * width + cc]);
                        }
                    }
                    let expected = sum / (total * total);
                    let got = Real::from(blurred[r as usize * width + c as usize]);
                    assert!(
                        (got - expected).abs() < 1e-5,
                        "{width}x{height} at ({c}, {r}): {got} against {expected}"
                    );
                }
            }
        }
    }

    /// Intensities made exactly as the model says (an albedo per sample times each photo's
    /// first-order lighting) give back each photo's shading, scaled to a mean of 1 where it
    /// sees, over each photo's own normals (one photo's expression turns half of them); a
    /// photo that does not see a sample does not disturb it.
    #[test]
    fn shading_recovers_each_photos_light() {
        let normals: Vec<Vector3<Real>> = (0..400)
            .map(|s| {
                let (a, b) = ((s % 20) as Real / 19.0 - 0.5, (s / 20) as Real / 19.0 - 0.5);
                Vector3::new(1.2 * a, 0.9 * b, 1.0).normalize()
            })
            .collect();
        let albedo: Vec<Real> = (0..400)
            .map(|s| 0.4 + 0.3 * ((s as Real * 0.37).sin() * 0.5 + 0.5))
            .collect();
        let lights = [[0.5, 0.4, 0.1, 0.3], [0.6, -0.3, 0.2, 0.2], [0.4, 0.0, -0.2, 0.5]];
        // Photo 1 sees the face with an expression: its lower half's normals turned.
        let photo_normals: Vec<Vec<Vector3<Real>>> = (0..3)
            .map(|i| {
                normals
                    .iter()
                    .enumerate()
                    .map(|(s, n)| {
                        if i == 1 && s >= 200 {
                            (n + Vector3::new(0.3, -0.2, 0.0)).normalize()
                        } else {
                            *n
                        }
                    })
                    .collect()
            })
            .collect();
        let shade = |i: usize, s: usize| {
            let (l, n) = (lights[i], photo_normals[i][s]);
            l[0] + l[1] * n.x + l[2] * n.y + l[3] * n.z
        };
        // Photo 2 does not see the left quarter of the samples.
        let sees = |i: usize, s: usize| !(i == 2 && s % 20 < 5);
        let raw: Vec<Vec<Option<Real>>> = (0..3)
            .map(|i| {
                (0..400)
                    .map(|s| sees(i, s).then(|| albedo[s] * shade(i, s)))
                    .collect()
            })
            .collect();
        let visibility: Vec<Vec<Real>> = (0..3)
            .map(|i| (0..400).map(|s| if sees(i, s) { 1.0 } else { 0.0 }).collect())
            .collect();
        let fitted = fit_shading(&raw, &visibility, &photo_normals);
        assert_eq!(fitted.len(), 3);
        // The photos' normals must be each photo's: one set of normals for all three does
        // not explain photo 1.
        let shared = fit_shading(&raw, &visibility, &[&normals[..]; 3]);
        let expected = |s: usize| {
            let mean = (0..400).map(|t| shade(1, t)).sum::<Real>() / 400.0;
            shade(1, s) / mean
        };
        assert!((200..400).any(|s| (shared[1][s] - expected(s)).abs() > 0.05 * expected(s)));
        for (i, fitted) in fitted.iter().enumerate() {
            let seen: Vec<usize> = (0..400).filter(|&s| sees(i, s)).collect();
            let mean = seen.iter().map(|&s| shade(i, s)).sum::<Real>() / seen.len() as Real;
            for &s in &seen {
                let expected = shade(i, s) / mean;
                assert!(
                    (fitted[s] - expected).abs() < 0.02 * expected,
                    "photo {i}, sample {s}: {} against {expected}",
                    fitted[s]
                );
            }
        }
    }
}
