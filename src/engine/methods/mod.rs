//! The transfer methods and the one registry that lists them (DESIGN.md "Layout": methods/).
//!
//! A method is a folder under `methods/` holding a type that implements [`Method`], plus one
//! line in [`Registry::builtin`]. The pipeline, the CLI and the service know methods only through
//! this trait: their id, the inputs they read ([`InputSpec`]), their params schema, the params
//! check (run at submission and again inside the job), `run`, and the error categories of
//! [`MethodError`]. What a method returns ([`MethodOutput`]) says which asset its edits apply to,
//! the edits ([`crate::engine::asset::edits::Edit`]), extra result files, warnings and its report.
//!
//! Shared building blocks: [`align`] (similarity from correspondences), [`correspondence`]
//! (resolving constraint places onto surfaces), [`output`] (writing an N-channel field into an
//! asset's UV layout or a vertex attribute), [`color_output`] (its base-colour form), [`params`]
//! (params schemas derived from the Params structs and the range check that reads them),
//! [`shared_params`] (options several methods share), and [`constraints_schema`] (the whole
//! constraints schema, `api/constraints.schema.json`).

pub mod align;
pub mod color_output;
pub mod correlation;
pub mod correspondence;
pub mod detail;
pub mod elastiface;
pub mod meshmatch;
pub mod output;
pub mod params;
pub mod pattern;
pub mod project;
pub mod shared_params;
pub mod tangents;

mod method;
mod schema;

pub use method::{
    atlas_working_set, texture_working_set, InputSpec, InputUse, Method, MethodError, MethodInput,
    MethodOutput, PatternImage, ResultFile, WorkingSet, TEXEL_BYTES,
};
pub use schema::{constraints_schema, constraints_schema_for, constraints_schema_json};
pub use shared_params::SharedParams;

use crate::engine::asset::constraints::MethodId;
use crate::engine::asset::Asset;
use crate::engine::mesh::{build_surface, Surface, WeldParams};

/// The methods a pipeline can run. [`Registry::builtin`] is the list retex ships; tests may build
/// a registry with more (e.g. a method for an id that is not implemented yet).
#[derive(Clone)]
pub struct Registry {
    methods: Vec<&'static dyn Method>,
}

impl std::fmt::Debug for Registry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list()
            .entries(self.methods.iter().map(|m| m.id()))
            .finish()
    }
}

impl Registry {
    /// Every method retex implements: one line per method.
    pub fn builtin() -> Self {
        Self {
            methods: vec![
                &project::Project,
                &meshmatch::MeshMatch,
                &elastiface::Elastiface,
                &correlation::Correlation,
                &pattern::Pattern,
                &detail::Detail,
            ],
        }
    }

    /// The same registry with `method` added (replacing one with the same id).
    pub fn with(mut self, method: &'static dyn Method) -> Self {
        self.methods.retain(|m| m.id() != method.id());
        self.methods.push(method);
        self
    }

    /// The same registry without the method `id` (tests of the not-implemented path, now that
    /// every id has a method).
    pub fn without(mut self, id: MethodId) -> Self {
        self.methods.retain(|m| m.id() != id);
        self
    }

    /// The method with this id, if implemented.
    pub fn get(&self, id: MethodId) -> Option<&'static dyn Method> {
        self.methods.iter().copied().find(|m| m.id() == id)
    }

    /// Every registered method, in registration order.
    pub fn methods(&self) -> impl Iterator<Item = &'static dyn Method> + '_ {
        self.methods.iter().copied()
    }

    /// The implemented ids, comma-separated (`project, meshmatch`), for messages.
    pub fn available(&self) -> String {
        self.methods
            .iter()
            .map(|m| m.id().as_str())
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl Default for Registry {
    fn default() -> Self {
        Self::builtin()
    }
}

/// The welded surface of an input `asset` (`side`: `"source"` or `"target"`); a mesh that
/// cannot be built is a [`MethodError::Mesh`] naming the side. Shared by the methods under
/// `methods/` that weld their inputs the same way (`correlation`, `elastiface`).
fn surface_of(
    asset: &Asset,
    weld: &WeldParams,
    side: &'static str,
) -> Result<Surface, MethodError> {
    build_surface(asset, weld).map_err(|source| MethodError::Mesh { side, source })
}
