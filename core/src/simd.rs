//! Runtime choice of the instruction set for loops written to vectorise.
//!
//! The workspace is built for x86-64-v2 (`.cargo/config.toml`: SSE4.2, 4 f32 or 2 f64
//! lanes), so that one binary runs on every x86-64 CPU since about 2009. Loops that are
//! written to vectorise (the elevation map's input stage, the synthetic renderer's texture)
//! run, on a CPU with AVX2 and FMA, a second copy of the same code compiled for it (8 f32
//! or 4 f64 lanes), chosen at each call by [`dispatch`] through `pulp` (faer's SIMD layer,
//! which the workspace already builds), so the project keeps no `unsafe` code. Both copies
//! compute the same values bit for bit as long as the loops are element-wise (no float sum
//! reordered): Rust never contracts a multiply and an add into an FMA on its own. The
//! users' tests compare the two copies.
//!
//! The pattern: a function's arguments become a struct whose `pulp::WithSimd::with_simd`
//! (`#[inline(always)]`) calls the function's `#[inline(always)]` body; `pulp` compiles
//! that once per instruction set, so the source exists once.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;

/// Set by [`force_portable`].
static PORTABLE: AtomicBool = AtomicBool::new(false);

/// Makes later dispatched loops run the portable (x86-64-v2) copy even where the CPU has
/// AVX2 (`true`), or the fastest copy the CPU runs again (`false`). For benchmarks, which
/// time both in one run (`stride bench map --portable`), and for tests; results do not
/// change. Process-wide.
pub fn force_portable(portable: bool) {
    PORTABLE.store(portable, Ordering::Relaxed);
}

/// The instruction set the dispatched loops use now: `"avx2"` or `"portable"` (for
/// reports).
pub fn instruction_set() -> &'static str {
    match arch() {
        pulp::Arch::Scalar => "portable",
        _ => "avx2",
    }
}

/// The best instruction set of this CPU that `pulp` offers (probed once), unless
/// [`force_portable`] asks for the portable one.
fn arch() -> pulp::Arch {
    static BEST: OnceLock<pulp::Arch> = OnceLock::new();
    if PORTABLE.load(Ordering::Relaxed) {
        pulp::Arch::Scalar
    } else {
        *BEST.get_or_init(pulp::Arch::new)
    }
}

/// Runs `op` in the copy compiled for the instruction set of [`instruction_set`].
#[inline(always)]
pub fn dispatch<Op: pulp::WithSimd>(op: Op) -> Op::Output {
    arch().dispatch(op)
}
