//! Constraints JSON v1: the job description shared by every method (method id, seed,
//! correspondences, output options, method parameters).
//!
//! All fields but `version` are optional; unknown fields are errors. Parse errors name the JSON
//! path that failed (`correspondences[1].target[0].point`), so a pipeline engineer can fix the
//! file without guessing. Correspondences are parsed here and resolved onto the meshes by
//! [`crate::engine::methods::correspondence`]. The JSON Schema is `api/constraints.schema.json`.

use serde::{Deserialize, Serialize};

/// The method ids retex knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MethodId {
    /// Closest-point projection (the baseline every baker has).
    #[default]
    Project,
    /// Chen et al. 2012, non-parametric texture transfer (MeshMatch).
    Meshmatch,
    /// Zell & Botsch 2013, ElastiFace.
    Elastiface,
    /// Mertens et al. 2006, texture transfer using geometry correlation.
    Correlation,
    /// Soler et al. 2002, hierarchical pattern mapping.
    Pattern,
    /// Berkiten et al. 2017, learning detail transfer.
    Detail,
}

impl MethodId {
    /// The id as written in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            MethodId::Project => "project",
            MethodId::Meshmatch => "meshmatch",
            MethodId::Elastiface => "elastiface",
            MethodId::Correlation => "correlation",
            MethodId::Pattern => "pattern",
            MethodId::Detail => "detail",
        }
    }

    /// Parses a method id (as given on the command line).
    pub fn parse(s: &str) -> Result<Self, ConstraintsError> {
        serde_json::from_value(serde_json::Value::String(s.to_string())).map_err(|_| ConstraintsError {
            path: "method".into(),
            message: format!(
                "unknown method {s:?}: expected one of project, meshmatch, elastiface, correlation, pattern, detail"
            ),
        })
    }
}

/// The vertex of a primitive, as `{"vertex": {"mesh": 0, "primitive": 1, "index": 7}}`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VertexRef {
    /// glTF mesh index.
    pub mesh: usize,
    /// Primitive index within the mesh.
    pub primitive: usize,
    /// Vertex index within the primitive's attributes.
    pub index: usize,
}

/// A place on a mesh, in one of three forms.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged, deny_unknown_fields)]
pub enum SurfaceRef {
    /// A world-space point; snapped to the nearest surface point.
    Point {
        /// x, y, z in the asset's world units.
        point: [f64; 3],
    },
    /// A point inside a triangle of a primitive.
    Triangle {
        /// glTF mesh index.
        mesh: usize,
        /// Primitive index within the mesh.
        primitive: usize,
        /// Triangle index within the primitive (after strip/fan conversion).
        triangle: usize,
        /// Barycentric weights of the triangle's 3 corners, each >= 0, summing to 1.
        barycentric: [f64; 3],
    },
    /// A vertex of a primitive.
    Vertex {
        /// The vertex.
        vertex: VertexRef,
    },
}

/// One or several places (MeshMatch allows one source point to match several target points).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum OneOrMany {
    /// A single place.
    One(SurfaceRef),
    /// Several places.
    Many(Vec<SurfaceRef>),
}

impl OneOrMany {
    /// The places as a slice.
    pub fn as_slice(&self) -> &[SurfaceRef] {
        match self {
            OneOrMany::One(r) => std::slice::from_ref(r),
            OneOrMany::Many(v) => v,
        }
    }

    /// Whether the list form was used (for JSON paths: `target[1]` vs `target`).
    pub fn is_list(&self) -> bool {
        matches!(self, OneOrMany::Many(_))
    }
}

/// A user-given correspondence between the source and one or several target places.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Correspondence {
    /// The place on the source.
    pub source: SurfaceRef,
    /// The place(s) on the target.
    pub target: OneOrMany,
}

/// Container format of the output.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum OutputFormat {
    /// Binary glTF, everything in one file.
    #[default]
    Glb,
    /// JSON glTF with buffers and images embedded as data: URIs.
    Gltf,
}

/// Output options.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputOptions {
    /// Width and height of each baked texture, in texels. Default 2048. Range 16..=8192.
    pub texture_size: u32,
    /// Padding around UV islands, in texels. Default 16. Range 0..=256.
    pub padding: u32,
    /// Also write the transferred color as COLOR_0 on the target's vertices. Default false.
    pub vertex_colors: bool,
    /// Output container. Default `glb`.
    pub format: OutputFormat,
}

impl Default for OutputOptions {
    fn default() -> Self {
        Self {
            texture_size: 2048,
            padding: 16,
            vertex_colors: false,
            format: OutputFormat::Glb,
        }
    }
}

/// Constraints JSON v1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Constraints {
    /// Must be 1.
    pub version: u32,
    /// The method; default `project`.
    #[serde(default)]
    pub method: MethodId,
    /// Seed of every random choice. Default 1.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// User correspondences. Default none.
    #[serde(default)]
    pub correspondences: Vec<Correspondence>,
    /// Output options.
    #[serde(default)]
    pub output: OutputOptions,
    /// Method parameters, validated by the method (unknown fields are errors). Default `{}`.
    #[serde(default = "empty_object")]
    pub params: serde_json::Value,
}

fn default_seed() -> u64 {
    1
}

fn empty_object() -> serde_json::Value {
    serde_json::Value::Object(Default::default())
}

impl Default for Constraints {
    fn default() -> Self {
        Self {
            version: 1,
            method: MethodId::Project,
            seed: 1,
            correspondences: Vec::new(),
            output: OutputOptions::default(),
            params: empty_object(),
        }
    }
}

/// A constraints file that cannot be used, with the JSON path at fault.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("constraints {path}: {message}")]
pub struct ConstraintsError {
    /// JSON path of the offending value (`.` for the document itself).
    pub path: String,
    /// What is wrong, lowercase.
    pub message: String,
}

impl ConstraintsError {
    /// An error at `path`.
    pub fn new(path: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Largest constraints document accepted, in bytes.
pub const MAX_CONSTRAINTS_BYTES: usize = 4 << 20;
/// Most correspondences accepted.
pub const MAX_CORRESPONDENCES: usize = 10_000;

impl Constraints {
    /// Parses and validates a constraints document.
    pub fn from_json(bytes: &[u8]) -> Result<Self, ConstraintsError> {
        if bytes.len() > MAX_CONSTRAINTS_BYTES {
            return Err(ConstraintsError::new(
                ".",
                format!(
                    "document of {} bytes exceeds the limit of {MAX_CONSTRAINTS_BYTES} bytes",
                    bytes.len()
                ),
            ));
        }
        let de = &mut serde_json::Deserializer::from_slice(bytes);
        let parsed: Constraints = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            ConstraintsError::new(path, e.into_inner().to_string())
        })?;
        parsed.validate()?;
        Ok(parsed)
    }

    /// Checks ranges that serde cannot express.
    pub fn validate(&self) -> Result<(), ConstraintsError> {
        if self.version != 1 {
            return Err(ConstraintsError::new(
                "version",
                format!("unsupported version {}: only 1 is known", self.version),
            ));
        }
        let o = &self.output;
        if !(16..=8192).contains(&o.texture_size) {
            return Err(ConstraintsError::new(
                "output.texture_size",
                format!("{} is outside the range 16..=8192", o.texture_size),
            ));
        }
        if o.padding > 256 {
            return Err(ConstraintsError::new(
                "output.padding",
                format!("{} is outside the range 0..=256", o.padding),
            ));
        }
        if !self.params.is_object() {
            return Err(ConstraintsError::new("params", "must be an object"));
        }
        if self.correspondences.len() > MAX_CORRESPONDENCES {
            return Err(ConstraintsError::new(
                "correspondences",
                format!(
                    "{} correspondences exceed the limit of {MAX_CORRESPONDENCES}",
                    self.correspondences.len()
                ),
            ));
        }
        for (i, c) in self.correspondences.iter().enumerate() {
            check_ref(&c.source, &format!("correspondences[{i}].source"))?;
            if c.target.as_slice().is_empty() {
                return Err(ConstraintsError::new(
                    format!("correspondences[{i}].target"),
                    "needs at least one place",
                ));
            }
            for (j, t) in c.target.as_slice().iter().enumerate() {
                check_ref(t, &target_path(i, j, c.target.is_list()))?;
            }
        }
        Ok(())
    }

    /// Deserializes `params` into a method's parameter struct (which should deny unknown fields),
    /// with errors naming `params.<field>`.
    pub fn method_params<P: serde::de::DeserializeOwned>(&self) -> Result<P, ConstraintsError> {
        serde_path_to_error::deserialize(&self.params).map_err(|e| {
            let inner = e.path().to_string();
            let path = if inner == "." {
                "params".to_string()
            } else {
                format!("params.{inner}")
            };
            ConstraintsError::new(path, e.into_inner().to_string())
        })
    }
}

/// JSON path of target place `j` of correspondence `i`.
pub fn target_path(i: usize, j: usize, list: bool) -> String {
    if list {
        format!("correspondences[{i}].target[{j}]")
    } else {
        format!("correspondences[{i}].target")
    }
}

fn check_ref(r: &SurfaceRef, path: &str) -> Result<(), ConstraintsError> {
    match r {
        SurfaceRef::Point { point } => {
            if point.iter().any(|c| !c.is_finite()) {
                return Err(ConstraintsError::new(
                    format!("{path}.point"),
                    "coordinates must be finite",
                ));
            }
        }
        SurfaceRef::Triangle { barycentric, .. } => {
            let sum: f64 = barycentric.iter().sum();
            if barycentric.iter().any(|b| !b.is_finite() || *b < -1e-6) || (sum - 1.0).abs() > 1e-3
            {
                return Err(ConstraintsError::new(
                    format!("{path}.barycentric"),
                    format!("{barycentric:?} is not a barycentric coordinate: each must be >= 0 and they must sum to 1"),
                ));
            }
        }
        SurfaceRef::Vertex { .. } => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_issue_example_parses() {
        let json = br#"{
          "version": 1, "method": "project", "seed": 1,
          "correspondences": [
            {"source": {"point": [0.1, 0.5, 0.2]}, "target": {"point": [0.0, 0.6, 0.1]}},
            {"source": {"mesh": 0, "primitive": 0, "triangle": 512, "barycentric": [0.2, 0.3, 0.5]},
             "target": [{"point": [0.3, 0.1, 0.0]}, {"vertex": {"mesh": 0, "primitive": 1, "index": 7}}]}
          ],
          "output": {"texture_size": 2048, "padding": 16, "vertex_colors": false, "format": "glb"},
          "params": {}
        }"#;
        let c = Constraints::from_json(json).unwrap();
        assert_eq!(c.correspondences.len(), 2);
        assert_eq!(c.correspondences[1].target.as_slice().len(), 2);
        assert!(matches!(
            c.correspondences[1].target.as_slice()[1],
            SurfaceRef::Vertex { .. }
        ));
    }

    #[test]
    fn only_version_is_required() {
        let c = Constraints::from_json(br#"{"version": 1}"#).unwrap();
        assert_eq!(c, Constraints::default());
        let e = Constraints::from_json(br#"{}"#).unwrap_err();
        assert!(e.message.contains("version"), "{e}");
    }

    #[test]
    fn errors_name_the_json_path() {
        let e = Constraints::from_json(br#"{"version": 1, "method": "magic"}"#).unwrap_err();
        assert_eq!(e.path, "method");
        let e = Constraints::from_json(br#"{"version": 1, "output": {"texture_size": 9000}}"#)
            .unwrap_err();
        assert_eq!(e.path, "output.texture_size");
        let e =
            Constraints::from_json(br#"{"version": 1, "output": {"colour": true}}"#).unwrap_err();
        assert!(e.path.starts_with("output"), "{e}");
        let e = Constraints::from_json(
            br#"{"version": 1, "correspondences": [{"source": {"point": [0,0,0]}, "target": [{"point": [0,0,0]},
                {"mesh": 0, "primitive": 0, "triangle": 1, "barycentric": [0.5, 0.6, 0.1]}]}]}"#,
        )
        .unwrap_err();
        assert_eq!(e.path, "correspondences[0].target[1].barycentric");
        let e = Constraints::from_json(br#"{"version": 2}"#).unwrap_err();
        assert_eq!(e.path, "version");
    }

    #[test]
    fn unknown_params_are_rejected_with_their_path() {
        #[derive(Debug, Deserialize, Default)]
        #[serde(default, deny_unknown_fields)]
        struct P {
            #[allow(dead_code)]
            max_distance: Option<f32>,
        }
        let c =
            Constraints::from_json(br#"{"version": 1, "params": {"max_distanse": 1}}"#).unwrap();
        let e = c.method_params::<P>().unwrap_err();
        assert!(e.path.starts_with("params"), "{e}");
        assert!(e.message.contains("max_distanse"), "{e}");
        let c = Constraints::from_json(br#"{"version": 1, "params": {"max_distance": "far"}}"#)
            .unwrap();
        let e = c.method_params::<P>().unwrap_err();
        assert_eq!(e.path, "params.max_distance");
    }
}
