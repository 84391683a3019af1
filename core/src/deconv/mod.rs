//! Deconvolution: PSFs, Wiener, Richardson-Lucy (being written).
