//! The `contacts` kernel's layouts (`shaders/contacts.wgsl`): its source,
//! specialised for the scene's size, the uniform block and the placed-grid
//! struct, named and laid out as in the WGSL (checked field by field by a
//! test), and its loop budget. The dispatch, which takes the physical
//! scene, is `physical::gpu`; its CPU twin is `physical::contacts`.

use bytemuck::{Pod, Zeroable};

/// The WGSL source of the kernel.
pub const CONTACTS_WGSL: &str = include_str!("../../shaders/contacts.wgsl");

/// The kernel's source with its private scene arrays sized for `planes`
/// planes and `grids` grids (WGSL cannot size private arrays by override
/// constants).
pub fn contacts_source(planes: usize, grids: usize) -> String {
    let src = CONTACTS_WGSL
        .replace("const PLANE_SLOTS: u32 = 4u;", &format!("const PLANE_SLOTS: u32 = {}u;", planes.max(1)))
        .replace("const GRID_SLOTS: u32 = 16u;", &format!("const GRID_SLOTS: u32 = {}u;", grids.max(1)));
    debug_assert!(src.contains(&format!("GRID_SLOTS: u32 = {}u;", grids.max(1))));
    src
}

/// Most planes the kernel takes (they live in the uniform block).
pub const MAX_PLANES: usize = 4;
/// Most placed grids (other objects) the kernel takes (uniform block too).
pub const MAX_GRIDS: usize = 16;

/// Invocations per workgroup (`WG` in the shader; checked by a test).
pub const WG: u32 = 64;

/// Uniform parameters (`ContactParams` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct ContactParams {
    pub n_hyp: u32,
    pub n_samples: u32,
    pub n_planes: u32,
    pub n_grids: u32,
    pub eps: f32,
    pub support_cos: f32,
    pub write_deltas: u32,
    pub words: u32,
    /// The sample words `[word_begin, word_end)` this dispatch classifies
    /// (a dispatch continues the records of the one before it unless
    /// `word_begin` is 0): see [`words_per_dispatch`].
    pub word_begin: u32,
    pub word_end: u32,
    pub pad: [u32; 2],
    pub gravity: [f32; 4],
    pub planes: [[f32; 4]; MAX_PLANES],
    pub grids: [GpuGrid; MAX_GRIDS],
}
const _: () = assert!(std::mem::size_of::<ContactParams>() == 128 + 96 * MAX_GRIDS);

/// Loop iterations one invocation may run on lavapipe, with a margin below
/// llvmpipe's silent cap of 65,535 (all loops of an invocation together;
/// past it every loop ends early and the results are wrong, not an error).
pub const LOOP_BUDGET: usize = 60_000;

/// Sample words (32 samples each) one dispatch may classify so that an
/// invocation stays within [`LOOP_BUDGET`]: each sample runs its own
/// iteration plus one per plane and one per grid (the scene loops are not
/// always unrolled), each word one more, plus the per-hypothesis setup.
pub fn words_per_dispatch(planes: usize, grids: usize) -> usize {
    let per_word = 32 * (1 + planes + grids) + 1;
    let setup = planes + 4 * grids + 1;
    ((LOOP_BUDGET - setup) / per_word).max(1)
}

/// One placed grid (`GpuGrid` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct GpuGrid {
    pub inv: [[f32; 4]; 3],
    pub origin: [f32; 4],
    pub upper: [f32; 4],
    pub dims: [u32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuGrid>() == 96);


#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::{ContactRecord, GpuPose};

    /// The WGSL structs match the Rust ones field by field (naga's layouter).
    #[test]
    fn wgsl_structs_match_rust_field_by_field() {
        use crate::kernels::wgsl_layout::assert_layout;
        use std::mem::{offset_of, size_of};
        let src = CONTACTS_WGSL;
        macro_rules! same {
            ($t:ty, $($f:ident),+) => { &[$((stringify!($f), offset_of!($t, $f))),+] };
        }
        let pad = offset_of!(ContactParams, pad);
        let mut params: Vec<(&str, usize)> =
            same!(ContactParams, n_hyp, n_samples, n_planes, n_grids, eps, support_cos, write_deltas, words, word_begin, word_end, gravity, planes, grids).to_vec();
        params.extend([("pad0", pad), ("pad1", pad + 4)]);
        assert_layout(src, "ContactParams", size_of::<ContactParams>(), &params);
        assert_layout(src, "GpuGrid", size_of::<GpuGrid>(), same!(GpuGrid, inv, origin, upper, dims));
        assert_layout(src, "GpuPose", size_of::<GpuPose>(), same!(GpuPose, rows));
        assert_layout(src, "ContactRecord", size_of::<ContactRecord>(), same!(ContactRecord, intersecting, contact, supported, min_delta));
        assert!(CONTACTS_WGSL.contains(&format!("const WG: u32 = {WG}u;")));
        assert!(CONTACTS_WGSL.contains(&format!("const PLANE_SLOTS: u32 = {MAX_PLANES}u;")));
        assert!(CONTACTS_WGSL.contains(&format!("const GRID_SLOTS: u32 = {MAX_GRIDS}u;")));
    }

}
