//! The errors of glTF ingest: one variant per way an upload can be wrong, each carrying what was
//! wrong and where (file name, JSON path, buffer / buffer view / accessor / image / node index,
//! and the limit that was exceeded).
//!
//! The service maps each variant to one problem type; see [`IngestError::kind`]. Messages are
//! lowercase sentences without a trailing period. The GLB container errors live in
//! [`super::glb::GlbError`] and are wrapped by [`IngestError::Glb`].

use super::glb::GlbError;

/// Why an upload could not be loaded as a glTF 2.0 asset.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IngestError {
    /// The named main file is not in the upload.
    #[error("main file {name:?} is not in the upload")]
    MissingMain {
        /// The name that was asked for.
        name: String,
    },
    /// The main file has zero bytes.
    #[error(
        "file {name:?} is empty (0 bytes): retex reads glTF 2.0 (.glb, or .gltf with its files)"
    )]
    EmptyFile {
        /// The file name.
        name: String,
    },
    /// The main file is another format (an OBJ, an image, text...), recognized by its first
    /// bytes ([`super::sniff`]).
    #[error(
        "{name:?} is {format}, not glTF: retex reads glTF 2.0 (.glb, or .gltf with its files){advice}"
    )]
    NotGltf {
        /// The file name.
        name: String,
        /// What the file is, e.g. `a Wavefront OBJ file`.
        format: &'static str,
        /// What to do instead, starting with `; ` (empty when there is nothing to add).
        advice: String,
    },
    /// The upload (all blobs together) is larger than `max_input_bytes`.
    #[error("the upload has {bytes} bytes, over the limit of {max}")]
    InputTooLarge {
        /// Total bytes.
        bytes: u64,
        /// The limit.
        max: u64,
    },
    /// The GLB container is malformed.
    #[error("glb container: {0}")]
    Glb(#[from] GlbError),
    /// The JSON text is larger than `max_json_bytes`.
    #[error("the glTF JSON has {bytes} bytes, over the limit of {max}")]
    JsonTooLarge {
        /// JSON size in bytes.
        bytes: u64,
        /// The limit.
        max: u64,
    },
    /// The JSON does not parse (syntax, byte order mark, number out of range, nesting too deep).
    #[error("invalid json at line {line} column {column}: {message}")]
    InvalidJson {
        /// 1-based line (0 when unknown).
        line: usize,
        /// 1-based column (0 when unknown).
        column: usize,
        /// The parser's message.
        message: String,
    },
    /// The JSON parses but is not a glTF 2.0 document (wrong type or missing required property).
    #[error("{path}: not valid gltf: {message}")]
    InvalidDocument {
        /// JSON path of the offending object, e.g. `accessors[3]` (or `/` when not located).
        path: String,
        /// The schema error.
        message: String,
    },
    /// `asset.version` is not 2.x.
    #[error("asset.version {version:?} is not supported: only glTF 2.x is")]
    UnsupportedVersion {
        /// The declared version.
        version: String,
    },
    /// An extension in `extensionsRequired` that retex cannot honour.
    #[error("required extension {0} is not supported")]
    UnsupportedExtension(String),
    /// A URI that would leave the upload: a scheme other than data:, an absolute path or `..`.
    #[error("uri {uri:?} of {what} is not allowed: only files in the upload and data: URIs are")]
    ForbiddenUri {
        /// What carries the URI, e.g. `buffers[0]`.
        what: String,
        /// The URI as written.
        uri: String,
    },
    /// A URI that is malformed (bad data: URI, bad percent-encoding, not UTF-8).
    #[error("uri of {what} is invalid: {reason}")]
    InvalidUri {
        /// What carries the URI, e.g. `images[2]`.
        what: String,
        /// Why.
        reason: String,
    },
    /// A data: URI larger than `max_data_uri_bytes`.
    #[error("data: uri of {what} holds about {bytes} bytes, over the limit of {max}")]
    DataUriTooLarge {
        /// What carries the URI.
        what: String,
        /// The (estimated) decoded size.
        bytes: u64,
        /// The limit.
        max: u64,
    },
    /// A relative URI names a file that is not in the upload.
    #[error("{what} refers to file {name:?}, which is not in the upload")]
    MissingFile {
        /// What carries the URI.
        what: String,
        /// The resolved file name inside the upload.
        name: String,
    },
    /// A buffer without a URI that is not the GLB BIN chunk.
    #[error("buffers[{buffer}] has no uri and is not the glb binary chunk")]
    BufferWithoutData {
        /// Buffer index.
        buffer: usize,
    },
    /// A buffer's data does not have its declared `byteLength`.
    #[error("buffers[{buffer}] declares byteLength {declared} but its data has {actual} bytes")]
    BufferLengthMismatch {
        /// Buffer index.
        buffer: usize,
        /// `byteLength`.
        declared: u64,
        /// Bytes actually present.
        actual: u64,
    },
    /// An index in the JSON that points at nothing.
    #[error("{path} refers to {target}[{index}], which does not exist ({count} present)")]
    UnresolvedReference {
        /// JSON path of the reference, e.g. `meshes[0].primitives[1].indices`.
        path: String,
        /// The array it indexes, e.g. `accessors`.
        target: &'static str,
        /// The index.
        index: usize,
        /// Length of that array.
        count: usize,
    },
    /// A buffer view that does not fit in its buffer.
    #[error("bufferViews[{view}]: range {offset}..{end} exceeds buffers[{buffer}] of {len} bytes")]
    BufferViewOutOfRange {
        /// Buffer view index.
        view: usize,
        /// Buffer index.
        buffer: usize,
        /// Start byte.
        offset: u64,
        /// End byte (exclusive; saturated on overflow).
        end: u64,
        /// Buffer length.
        len: u64,
    },
    /// A buffer view whose `byteStride` is outside 4..=252 or not a multiple of 4.
    #[error(
        "bufferViews[{view}]: byteStride {stride} is invalid (must be 4..=252 and a multiple of 4)"
    )]
    InvalidStride {
        /// Buffer view index.
        view: usize,
        /// The stride.
        stride: u64,
    },
    /// An accessor whose elements do not fit in its buffer view.
    #[error(
        "accessors[{accessor}]: range {offset}..{end} exceeds bufferViews[{view}] of {len} bytes"
    )]
    AccessorOutOfRange {
        /// Accessor index.
        accessor: usize,
        /// Buffer view index.
        view: usize,
        /// First byte (within the view).
        offset: u64,
        /// End byte (within the view, exclusive; saturated on overflow).
        end: u64,
        /// View length.
        len: u64,
    },
    /// A buffer view stride smaller than the accessor's element.
    #[error("accessors[{accessor}]: byteStride {stride} of bufferViews[{view}] is smaller than its {element}-byte element")]
    StrideTooSmall {
        /// Accessor index.
        accessor: usize,
        /// Buffer view index.
        view: usize,
        /// The stride.
        stride: u64,
        /// Element size in bytes.
        element: u64,
    },
    /// An accessor that is malformed in some other way (bad type, misaligned offset, sparse).
    #[error("accessors[{accessor}]: {reason}")]
    InvalidAccessor {
        /// Accessor index.
        accessor: usize,
        /// Why.
        reason: String,
    },
    /// An accessor whose type or component type is not allowed for the attribute using it.
    #[error("{path}: accessors[{accessor}] is {found}, expected {expected}")]
    WrongAccessorType {
        /// JSON path of the use, e.g. `meshes[0].primitives[0].attributes.POSITION`.
        path: String,
        /// Accessor index.
        accessor: usize,
        /// What it is, e.g. `VEC2 of 5126`.
        found: String,
        /// What is allowed.
        expected: &'static str,
    },
    /// Attributes of one primitive with different counts.
    #[error("{path}: accessors[{accessor}] has {count} elements but POSITION has {expected}")]
    UnequalCount {
        /// JSON path of the attribute.
        path: String,
        /// Accessor index.
        accessor: usize,
        /// Its count.
        count: u64,
        /// POSITION's count.
        expected: u64,
    },
    /// A primitive without POSITION.
    #[error("{path} is missing")]
    MissingPosition {
        /// JSON path, e.g. `meshes[0].primitives[1].attributes.POSITION`.
        path: String,
    },
    /// A vertex index that is not below the vertex count.
    #[error("{path}: index {value} at position {position} of accessors[{accessor}] is not below the vertex count {vertex_count}")]
    IndexOutOfRange {
        /// JSON path of the indices.
        path: String,
        /// Accessor index.
        accessor: usize,
        /// Position in the index list.
        position: u64,
        /// The index value.
        value: u64,
        /// Number of vertices.
        vertex_count: u64,
    },
    /// An index equal to the maximum of its component type (a primitive restart value).
    #[error("{path}: index {value} at position {position} of accessors[{accessor}] is the primitive restart value, which glTF forbids")]
    PrimitiveRestartIndex {
        /// JSON path of the indices.
        path: String,
        /// Accessor index.
        accessor: usize,
        /// Position in the index list.
        position: u64,
        /// The index value (255, 65535 or 4294967295).
        value: u64,
    },
    /// NaN or infinity in vertex data that must be finite.
    #[error("{path}: element {element} of accessors[{accessor}] is not finite")]
    NonFinite {
        /// JSON path of the attribute.
        path: String,
        /// Accessor index.
        accessor: usize,
        /// Element index.
        element: u64,
    },
    /// More vertices (summed over primitives) than `max_vertices`.
    #[error("the asset has at least {count} vertices, over the limit of {max}")]
    TooManyVertices {
        /// Count so far.
        count: u64,
        /// The limit.
        max: u64,
    },
    /// More triangles (summed over primitives) than `max_triangles`.
    #[error("the asset has at least {count} triangles, over the limit of {max}")]
    TooManyTriangles {
        /// Count so far.
        count: u64,
        /// The limit.
        max: u64,
    },
    /// The images the job decodes would take more than `max_decoded_image_bytes` together;
    /// `image` is the one that brings the sum over the limit.
    #[error(
        "images[{image}] ({width}x{height}) decodes to {bytes} bytes, which brings the job's decoded images to {total} bytes, over max_decoded_image_bytes = {max}"
    )]
    ImageBudget {
        /// Image index (0 for the pattern).
        image: usize,
        /// Header width.
        width: u32,
        /// Header height.
        height: u32,
        /// Its decoded size.
        bytes: u64,
        /// The job's decoded bytes up to and including it.
        total: u64,
        /// The limit.
        max: u64,
    },
    /// The job's surfaces (every mesh instance of every model the method reads) would hold more
    /// vertices or triangles than `max_vertices` / `max_triangles`.
    #[error(
        "the job's meshes hold {count} {what} counting every mesh instance, over max_{what} = {max}"
    )]
    GeometryBudget {
        /// `vertices` or `triangles`.
        what: &'static str,
        /// The count over the inputs up to and including this one.
        count: u64,
        /// The limit.
        max: u64,
    },
    /// The node hierarchy is not a forest.
    #[error("nodes[{node}]: {reason}")]
    InvalidNodeHierarchy {
        /// A node on the cycle, or with two parents.
        node: usize,
        /// Why.
        reason: String,
    },
    /// The node hierarchy is deeper than `max_node_depth`.
    #[error("nodes[{node}] is at depth {depth}, over the limit of {max}")]
    NodeTooDeep {
        /// The node.
        node: usize,
        /// Its depth.
        depth: u64,
        /// The limit.
        max: u64,
    },
    /// A node transform (or world transform) with NaN or infinity.
    #[error("nodes[{node}]: transform is not finite")]
    NonFiniteTransform {
        /// The node.
        node: usize,
    },
    /// An image whose header dimensions exceed `max_image_side` or `max_image_pixels`.
    #[error("images[{image}]: {width}x{height} exceeds the limit of {max}")]
    ImageTooLarge {
        /// Image index.
        image: usize,
        /// Header width.
        width: u32,
        /// Header height.
        height: u32,
        /// The limit exceeded (a side in pixels, or a pixel count).
        max: u64,
    },
    /// An image whose bytes are not PNG or JPEG.
    #[error("images[{image}]: data is not a recognized image format (png or jpeg)")]
    UnrecognizedImage {
        /// Image index.
        image: usize,
    },
    /// An image that is recognized but corrupt, or could not be decoded under the limits.
    #[error("images[{image}]: {message}")]
    ImageDecode {
        /// Image index.
        image: usize,
        /// The decoder's message.
        message: String,
    },
    /// An image with neither a URI nor a buffer view.
    #[error("images[{image}] has neither uri nor bufferView")]
    ImageWithoutData {
        /// Image index.
        image: usize,
    },
    /// A bug: a panic inside the loader, caught.
    #[error("internal error while loading: {0}")]
    Internal(String),
}

impl IngestError {
    /// A short stable kebab-case name of the variant, for problem types and logs.
    pub fn kind(&self) -> &'static str {
        use IngestError::*;
        match self {
            MissingMain { .. } => "missing-main",
            EmptyFile { .. } => "empty-file",
            NotGltf { .. } => "not-gltf",
            InputTooLarge { .. } => "input-too-large",
            Glb(_) => "invalid-glb",
            JsonTooLarge { .. } => "json-too-large",
            InvalidJson { .. } => "invalid-json",
            InvalidDocument { .. } => "invalid-document",
            UnsupportedVersion { .. } => "unsupported-version",
            UnsupportedExtension(_) => "unsupported-extension",
            ForbiddenUri { .. } => "forbidden-uri",
            InvalidUri { .. } => "invalid-uri",
            DataUriTooLarge { .. } => "data-uri-too-large",
            MissingFile { .. } => "missing-file",
            BufferWithoutData { .. } => "buffer-without-data",
            BufferLengthMismatch { .. } => "buffer-length-mismatch",
            UnresolvedReference { .. } => "unresolved-reference",
            BufferViewOutOfRange { .. } => "buffer-view-out-of-range",
            InvalidStride { .. } => "invalid-stride",
            AccessorOutOfRange { .. } => "accessor-out-of-range",
            StrideTooSmall { .. } => "stride-too-small",
            InvalidAccessor { .. } => "invalid-accessor",
            WrongAccessorType { .. } => "wrong-accessor-type",
            UnequalCount { .. } => "unequal-count",
            MissingPosition { .. } => "missing-position",
            IndexOutOfRange { .. } => "index-out-of-range",
            PrimitiveRestartIndex { .. } => "primitive-restart-index",
            NonFinite { .. } => "non-finite",
            TooManyVertices { .. } => "too-many-vertices",
            TooManyTriangles { .. } => "too-many-triangles",
            ImageBudget { .. } => "image-budget-exceeded",
            GeometryBudget {
                what: "vertices", ..
            } => "too-many-vertices",
            GeometryBudget { .. } => "too-many-triangles",
            InvalidNodeHierarchy { .. } => "invalid-node-hierarchy",
            NodeTooDeep { .. } => "node-too-deep",
            NonFiniteTransform { .. } => "non-finite-transform",
            ImageTooLarge { .. } => "image-too-large",
            UnrecognizedImage { .. } => "unrecognized-image",
            ImageDecode { .. } => "image-decode",
            ImageWithoutData { .. } => "image-without-data",
            Internal(_) => "internal",
        }
    }
}
