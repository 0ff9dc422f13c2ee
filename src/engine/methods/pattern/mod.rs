//! The `pattern` method: hierarchical pattern mapping (Soler, Cani & Angelidis, SIGGRAPH 2002).
//!
//! Image side (§4.1 mask, §4.2 best fit, §4.4 relaxation): [`texture`], [`mask`], [`fit`],
//! [`relax`] and the 2-D FFTs they share ([`fft2`]).

pub mod fft2;
pub mod fit;
pub mod mask;
pub mod relax;
pub mod texture;
