//! Texture sampling (sRGB aware, wrap modes, KHR_texture_transform), UV-layout rasterization
//! (baking), padding, and PNG encoding.

pub mod bake;
pub mod color;
pub mod encode;
pub mod pad;
pub mod sample;
