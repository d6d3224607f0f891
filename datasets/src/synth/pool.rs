//! Per-pixel buffers kept from one frame to the next.
//!
//! A VGA frame's buffers (patch indices, `1/z`, incidence, accumulated colour) are several
//! megabytes each. Allocated afresh per frame, every page of them is a kernel page fault on
//! first write, which cost about 15 % of a frame's render time (`stride bench synth`,
//! 87 against 100 ms with the allocator told to keep its memory). The renderer lends
//! buffers from this pool and takes them back when a frame is done.

use super::raster::PatchBuffer;
use std::sync::{Mutex, PoisonError};

/// Buffers waiting to be lent, by kind. At most a few of each are kept.
#[derive(Debug, Default)]
pub(super) struct BufferPool {
    inner: Mutex<Buffers>,
}

#[derive(Debug, Default)]
struct Buffers {
    patches: Vec<PatchBuffer>,
    scalars: Vec<Vec<f32>>,
    colours: Vec<Vec<[f32; 3]>>,
}

/// Buffers of one kind kept at most (a frame lends two of each at a time).
const KEEP: usize = 4;

impl BufferPool {
    fn with<R>(&self, f: impl FnOnce(&mut Buffers) -> R) -> R {
        // A panic while holding the lock leaves only spare buffers behind: still usable.
        let mut guard = self.inner.lock().unwrap_or_else(PoisonError::into_inner);
        f(&mut guard)
    }

    /// A patch buffer (contents unspecified: the rasteriser resets it).
    pub(super) fn patch_buffer(&self) -> PatchBuffer {
        self.with(|b| b.patches.pop()).unwrap_or_default()
    }

    /// `n` zeros.
    pub(super) fn zeros(&self, n: usize) -> Vec<f32> {
        let mut v = self.with(|b| b.scalars.pop()).unwrap_or_default();
        v.clear();
        v.resize(n, 0.0);
        v
    }

    /// `n` black colours.
    pub(super) fn black(&self, n: usize) -> Vec<[f32; 3]> {
        let mut v = self.with(|b| b.colours.pop()).unwrap_or_default();
        v.clear();
        v.resize(n, [0.0; 3]);
        v
    }

    /// Takes a patch buffer back.
    pub(super) fn give_patches(&self, buffer: PatchBuffer) {
        self.with(|b| keep(&mut b.patches, buffer));
    }

    /// Takes a scalar buffer back.
    pub(super) fn give_scalars(&self, buffer: Vec<f32>) {
        self.with(|b| keep(&mut b.scalars, buffer));
    }

    /// Takes a colour buffer back.
    pub(super) fn give_colours(&self, buffer: Vec<[f32; 3]>) {
        self.with(|b| keep(&mut b.colours, buffer));
    }
}

fn keep<T>(spare: &mut Vec<T>, buffer: T) {
    if spare.len() < KEEP {
        spare.push(buffer);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lent_buffers_come_back_cleared() {
        let pool = BufferPool::default();
        let mut v = pool.zeros(4);
        v[1] = 3.0;
        let ptr = v.as_ptr();
        pool.give_scalars(v);
        let w = pool.zeros(4);
        assert_eq!(w, vec![0.0; 4]);
        assert_eq!(w.as_ptr(), ptr, "the same allocation is lent again");
        let c = pool.black(2);
        assert_eq!(c, vec![[0.0; 3]; 2]);
        for _ in 0..10 {
            pool.give_colours(vec![[1.0; 3]; 1]);
        }
        assert_eq!(pool.with(|b| b.colours.len()), KEEP);
    }
}
