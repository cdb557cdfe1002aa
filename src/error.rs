//! The crate's errors in one type for front ends ([`Error`]), and the error of a setting a
//! person gave ([`SettingError`]).
//!
//! Each module reports its own failures in its own typed error, with named fields (a
//! [`crate::mesh::MeshError`] names the file and the problem, a [`crate::compare::CompareError`]
//! the structure that is unusable); [`Error`] gathers them for code that calls several stages
//! and reports whatever went wrong, as the command line and the Python package do. Its
//! messages are the modules' own.

/// A setting that cannot be used: which (`snake_case`, as the Python keyword; the command
/// line's flag is the same with dashes), the value given, and what it should be.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{setting} {value}: {expected}")]
pub struct SettingError {
    /// The setting, `snake_case`.
    pub setting: &'static str,
    /// The value given, as written (words in backticks).
    pub value: String,
    /// What it should be.
    pub expected: String,
}

impl SettingError {
    /// A setting `setting` (`snake_case`) with the value `value` as written, which should be
    /// `expected`.
    pub fn new(setting: &'static str, value: impl Into<String>, expected: impl Into<String>) -> Self {
        SettingError {
            setting,
            value: value.into(),
            expected: expected.into(),
        }
    }

    /// The message as the command line writes it: `--FLAG VALUE: expected`, the flag being
    /// the setting with dashes.
    pub fn flag_message(&self) -> String {
        format!(
            "--{} {}: {}",
            self.setting.replace('_', "-"),
            self.value,
            self.expected
        )
    }
}

/// Whatever went wrong in the library, for front ends that call several stages: each variant
/// holds a module's own error, whose message it shows unchanged.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A setting out of range or unknown.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// Input photos or landmark files that cannot be gathered.
    #[error(transparent)]
    Input(#[from] crate::pipeline::InputError),
    /// An output folder or file that cannot be written.
    #[error(transparent)]
    Output(#[from] crate::io::OutputError),
    /// An image, depth map or other file that could not be encoded.
    #[error(transparent)]
    Encode(#[from] crate::io::EncodeError),
    /// A mesh file.
    #[error(transparent)]
    Mesh(#[from] crate::mesh::MeshError),
    /// A landmark file.
    #[error(transparent)]
    Landmarks(#[from] crate::landmarks::LandmarkError),
    /// The landmark model file.
    #[error(transparent)]
    Model(#[from] crate::landmarker::ModelError),
    /// A photo that cannot be decoded.
    #[error(transparent)]
    Photo(#[from] crate::align::PhotoError),
    /// A reference face file.
    #[error(transparent)]
    ReferenceFile(#[from] crate::reference::ReferenceFileError),
    /// A face-space mode file.
    #[error(transparent)]
    ModeFile(#[from] crate::face::modes::ModeFileError),
    /// Building a reference face.
    #[error(transparent)]
    Reference(#[from] crate::reference::ReferenceError),
    /// A reconstruction.
    #[error(transparent)]
    Pipeline(#[from] crate::pipeline::PipelineError),
    /// A batch of subjects.
    #[error(transparent)]
    Batch(#[from] crate::batch::BatchError),
    /// A comparison with a ground truth.
    #[error(transparent)]
    Compare(#[from] crate::compare::CompareError),
    /// The face surface.
    #[error(transparent)]
    Face(#[from] crate::face::FaceError),
    /// A 40-point structure.
    #[error(transparent)]
    Structure(#[from] crate::structure::StructureError),
    /// The B-spline kernel.
    #[error(transparent)]
    BSpline(#[from] crate::bspline::BSplineError),
    /// A surface file ([`crate::bspline::BSplineSurface::read_json`]).
    #[error(transparent)]
    SurfaceFile(#[from] crate::bspline::SurfaceFileError),
    /// The 2D alignment of the photos.
    #[error(transparent)]
    Align(#[from] crate::align::AlignError),
    /// The depth stage.
    #[error(transparent)]
    Depth(#[from] crate::depth::DepthError),
    /// Rendering a depth map or photo.
    #[error(transparent)]
    Render(#[from] crate::render::RenderError),
    /// The demo subject's scene.
    #[error(transparent)]
    Demo(#[from] crate::demo::DemoError),
}
