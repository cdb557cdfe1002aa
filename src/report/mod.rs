//! What a person looks at after a run: per-photo overlays ([`draw_overlay`]: the photo with
//! its face box, landmarks and the fitted face's points) and `report.html`
//! ([`report_page`]: one self-contained page with the summary, the pictures and the face in
//! an interactive 3D viewer).

mod overlay;
mod page;

pub use overlay::{FittedPoints, MAX_SIDE, MIN_SIDE, Overlay, PhotoStatus, draw_overlay, overlay_scale};
pub use page::{PageOptions, report_page};
