//! Texture sampling (sRGB aware, wrap modes, KHR_texture_transform), UV-layout rasterization
//! (baking), padding, PNG encoding, and a software turntable preview renderer.

pub mod bake;
pub mod color;
pub mod encode;
pub mod pad;
pub mod preview;
pub mod preview_normals;
pub mod sample;
