//! A reconstruction's settings as a person gives them (the command line's flags, the Python
//! package's keywords), checked and turned into [`PipelineOptions`] in one place.

use super::{PipelineOptions, Shape};
use crate::error::SettingError;
use crate::face::{Deformation, MeshOptions, TextureOptions, Units};
use crate::render::MAX_SIDE;

/// The settings of `splineface reconstruct`, `splineface batch` and the Python package's
/// `reconstruct`, unchecked; [`Settings::options`] checks them. The defaults are the command
/// line's.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Output units: `mm` or `canonical` (the paper's: 50 between the eye centres).
    pub units: String,
    /// The distance between the eye centres in millimetres, for `units = "mm"`.
    pub eye_distance: f64,
    /// Where the face's shape comes from: `space` or `deformed` ([`Shape`]).
    pub shape: String,
    /// The face-space fit's landmark noise per coordinate, canonical units.
    pub space_noise: f64,
    /// The prior deviation of each photo's expression weights.
    pub expression_sigma: f64,
    /// Fit an expression per photo (else every photo is taken as neutral).
    pub expressions: bool,
    /// Measure the jaw points against the face's outline in each photo ([`Shape::Space`]'s
    /// `outline`).
    pub outline: bool,
    /// Read an open mouth from the gaps between the inner lips where the landmarks have them
    /// ([`Shape::Space`]'s `lips`, at [`crate::face::LIP_WEIGHT`]; else 0). Off by default,
    /// by measurement.
    pub lips: bool,
    /// Refine the face with the photos' pixels ([`PipelineOptions::refine`]).
    pub refine: bool,
    /// With `refine`, also fit a depth displacement of every control point, the detail the
    /// face space cannot carry ([`crate::face::RefineOptions::field`]); else the refinement
    /// moves the space's weights and the cameras alone.
    pub displacement: bool,
    /// The deformation of `shape = "deformed"`: `local` or `affine`.
    pub deformation: String,
    /// Mesh vertex spacing, canonical units (0.1 to 20).
    pub spacing: f64,
    /// The depth map's larger side, pixels (16 to [`MAX_SIDE`]).
    pub depth_size: usize,
    /// The texture atlas's side, texels (16 to 8192), or `None` to take it from the photos
    /// ([`crate::face::automatic_atlas_side`]).
    pub texture_size: Option<u32>,
    /// The fewest usable photos (at least 1).
    pub min_photos: usize,
}

impl Default for Settings {
    fn default() -> Self {
        Settings {
            units: "mm".into(),
            eye_distance: crate::face::DEFAULT_EYE_DISTANCE_MM,
            shape: "space".into(),
            space_noise: Shape::DEFAULT_NOISE,
            expression_sigma: Shape::DEFAULT_EXPRESSION_SIGMA,
            expressions: true,
            outline: true,
            lips: false,
            refine: true,
            displacement: true,
            deformation: "local".into(),
            spacing: 1.0,
            depth_size: 512,
            texture_size: None,
            min_photos: super::MIN_PHOTOS,
        }
    }
}

impl Settings {
    /// The pipeline's options for these settings.
    ///
    /// # Errors
    /// The first setting that cannot be used ([`SettingError`]).
    pub fn options(&self) -> Result<PipelineOptions, SettingError> {
        let bad = |setting: &'static str, value: String, expected: &str| SettingError {
            setting,
            value,
            expected: expected.to_owned(),
        };
        let word = |w: &str| format!("`{w}`");
        let units = match self.units.as_str() {
            "mm" => {
                if !(self.eye_distance > 0.0 && self.eye_distance.is_finite()) {
                    return Err(bad(
                        "eye_distance",
                        self.eye_distance.to_string(),
                        "must be positive",
                    ));
                }
                Units::Millimetres {
                    eye_distance: self.eye_distance,
                }
            }
            "canonical" => Units::Canonical,
            other => return Err(bad("units", word(other), "expected mm or canonical")),
        };
        let deformation = match self.deformation.as_str() {
            "local" => Deformation::default(),
            "affine" => Deformation::Affine,
            other => return Err(bad("deformation", word(other), "expected local or affine")),
        };
        if !(self.space_noise > 0.0 && self.space_noise.is_finite()) {
            return Err(bad(
                "space_noise",
                self.space_noise.to_string(),
                "must be positive",
            ));
        }
        if !(self.expression_sigma > 0.0 && self.expression_sigma.is_finite()) {
            return Err(bad(
                "expression_sigma",
                self.expression_sigma.to_string(),
                "must be positive",
            ));
        }
        let shape = match self.shape.as_str() {
            "space" => Shape::Space {
                noise: self.space_noise,
                expressions: self.expressions.then_some(crate::face::ExpressionPrior {
                    sigma: self.expression_sigma,
                    ..crate::face::ExpressionPrior::DEFAULT
                }),
                outline: self.outline,
                lips: if self.lips { crate::face::LIP_WEIGHT } else { 0.0 },
            },
            "deformed" => Shape::Deformed,
            other => return Err(bad("shape", word(other), "expected space or deformed")),
        };
        if !(self.spacing >= 0.1 && self.spacing <= 20.0) {
            return Err(bad(
                "spacing",
                self.spacing.to_string(),
                "must be between 0.1 and 20 canonical units",
            ));
        }
        if !(16..=MAX_SIDE).contains(&self.depth_size) {
            return Err(bad(
                "depth_size",
                self.depth_size.to_string(),
                &format!("must be between 16 and {MAX_SIDE}"),
            ));
        }
        if self.min_photos == 0 {
            return Err(bad("min_photos", "0".into(), "must be at least 1"));
        }
        if let Some(size) = self.texture_size.filter(|s| !(16..=8192).contains(s)) {
            return Err(bad(
                "texture_size",
                size.to_string(),
                "must be between 16 and 8192",
            ));
        }
        Ok(PipelineOptions {
            units,
            min_photos: self.min_photos,
            deformation,
            shape,
            mesh: MeshOptions {
                spacing: self.spacing,
            },
            depth_map_size: self.depth_size,
            texture: TextureOptions {
                size: self.texture_size,
                ..TextureOptions::default()
            },
            refine: PipelineOptions::default()
                .refine
                .filter(|_| self.refine)
                .map(|r| crate::face::RefineOptions {
                    field: self.displacement,
                    ..r
                }),
            ..PipelineOptions::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_settings_are_the_default_options() {
        assert_eq!(Settings::default().options(), Ok(PipelineOptions::default()));
    }

    #[test]
    fn the_displacement_setting_turns_the_refinements_field_off_alone() {
        let refine = |settings: Settings| settings.options().map(|o| o.refine);
        let without = refine(Settings {
            displacement: false,
            ..Settings::default()
        })
        .expect("valid settings")
        .expect("a refinement");
        assert!(!without.field);
        assert_eq!(
            crate::face::RefineOptions {
                field: true,
                ..without
            },
            crate::face::RefineOptions::default()
        );
        let unrefined = Settings {
            refine: false,
            displacement: true,
            ..Settings::default()
        };
        assert_eq!(refine(unrefined), Ok(None));
    }

    #[test]
    fn each_bad_setting_is_named() {
        let cases: [(Settings, &str); 9] = [
            (
                Settings {
                    units: "inches".into(),
                    ..Settings::default()
                },
                "units `inches`: expected mm or canonical",
            ),
            (
                Settings {
                    eye_distance: -63.0,
                    ..Settings::default()
                },
                "eye_distance -63: must be positive",
            ),
            (
                Settings {
                    shape: "blob".into(),
                    ..Settings::default()
                },
                "shape `blob`: expected space or deformed",
            ),
            (
                Settings {
                    space_noise: f64::NAN,
                    ..Settings::default()
                },
                "space_noise NaN: must be positive",
            ),
            (
                Settings {
                    expression_sigma: 0.0,
                    ..Settings::default()
                },
                "expression_sigma 0: must be positive",
            ),
            (
                Settings {
                    deformation: "bend".into(),
                    ..Settings::default()
                },
                "deformation `bend`: expected local or affine",
            ),
            (
                Settings {
                    spacing: 0.01,
                    ..Settings::default()
                },
                "spacing 0.01: must be between 0.1 and 20 canonical units",
            ),
            (
                Settings {
                    texture_size: Some(8),
                    ..Settings::default()
                },
                "texture_size 8: must be between 16 and 8192",
            ),
            (
                Settings {
                    min_photos: 0,
                    ..Settings::default()
                },
                "min_photos 0: must be at least 1",
            ),
        ];
        for (settings, message) in cases {
            assert_eq!(settings.options().unwrap_err().to_string(), message);
        }
    }

    #[test]
    fn units_in_millimetres_keep_the_eye_distance() {
        let options = Settings {
            eye_distance: 60.0,
            refine: false,
            expressions: false,
            ..Settings::default()
        }
        .options()
        .unwrap();
        assert_eq!(options.units, Units::Millimetres { eye_distance: 60.0 });
        assert_eq!(options.refine, None);
        assert!(matches!(
            options.shape,
            Shape::Space {
                expressions: None,
                ..
            }
        ));
    }
}
