//! The pieces every convolution kernel shares, at the bottom of `kernels/` (nothing here
//! imports another kernel): a convolution's shape, what rides along before and after it, the
//! activation that follows it, the matrix product and the pointer that lets rayon tasks write
//! disjoint parts of one buffer, and the frame of a Winograd weight transform.

use rayon::prelude::*;

/// What follows a convolution.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    Identity,
    Relu,
    /// LeakyReLU with this negative slope (f64 as Burn's `leaky_relu` takes it).
    Leaky(f64),
}

/// Shapes of one convolution: `x` is `[batch, channels_in, height, width]`, the weight
/// `[channels_out, channels_in, kernel, kernel]`, dilation 1, `padding` on every side, the same
/// `stride` along both axes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ConvShape {
    pub batch: usize,
    pub channels_in: usize,
    pub channels_out: usize,
    pub height: usize,
    pub width: usize,
    pub kernel: usize,
    pub padding: usize,
    pub stride: usize,
}

impl ConvShape {
    pub fn out_height(&self) -> usize {
        (self.height + 2 * self.padding - self.kernel) / self.stride + 1
    }

    pub fn out_width(&self) -> usize {
        (self.width + 2 * self.padding - self.kernel) / self.stride + 1
    }

    /// Row stride of the padded image (and of the spread output gradient).
    pub(crate) fn padded_width(&self) -> usize {
        self.width + 2 * self.padding
    }

    /// The 1x1 unpadded case needs no padded copy: the image itself is the matrix.
    pub(crate) fn is_pointwise(&self) -> bool {
        self.kernel == 1 && self.padding == 0 && self.stride == 1
    }

    /// Elements per channel of the padded image: one spare row at the bottom, because the window
    /// of the last tap runs `kernel - 1` elements past the last padded row.
    pub(crate) fn padded_len(&self) -> usize {
        if self.is_pointwise() {
            self.height * self.width
        } else {
            (self.height + 2 * self.padding + 1) * self.padded_width()
        }
    }

    /// Columns of one output matrix: output rows at the padded row stride.
    pub(crate) fn columns(&self) -> usize {
        self.out_height() * self.padded_width()
    }

    /// The convolution that gives the input gradient: the output gradient, spread to stride 1
    /// (the size a stride-1 convolution's output would have), convolved with the weight
    /// transposed and flipped, padded by `kernel - 1 - padding`.
    pub fn transposed(&self) -> ConvShape {
        ConvShape {
            batch: self.batch,
            channels_in: self.channels_out,
            channels_out: self.channels_in,
            height: self.height + 2 * self.padding + 1 - self.kernel,
            width: self.width + 2 * self.padding + 1 - self.kernel,
            kernel: self.kernel,
            padding: self.kernel - 1 - self.padding,
            stride: 1,
        }
    }
}

/// `max(0, x * scale[c] + shift[c])` on each input channel `c` before the convolution: an
/// eval-mode batch norm and ReLU. Padding stays zero, as when the ReLU's output is padded.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Prologue<'a> {
    pub scale: &'a [f32],
    pub shift: &'a [f32],
}

/// `activation(y * scale[o] + shift[o])` on each output channel `o`, where each is optional.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Epilogue<'a> {
    pub scale: Option<&'a [f32]>,
    pub shift: Option<&'a [f32]>,
    pub activation: Activation,
}

impl<'a> Epilogue<'a> {
    pub fn bias(bias: Option<&'a [f32]>, activation: Activation) -> Self {
        Epilogue { scale: None, shift: bias, activation }
    }

    pub(crate) fn is_identity(&self) -> bool {
        self.scale.is_none() && self.shift.is_none() && self.activation == Activation::Identity
    }

    #[inline(always)]
    pub(crate) fn apply(&self, channel: usize, row: &mut [f32]) {
        let scale = self.scale.map_or(1.0, |s| s[channel]);
        let shift = self.shift.map_or(0.0, |s| s[channel]);
        match self.activation {
            Activation::Identity => row.iter_mut().for_each(|v| *v = *v * scale + shift),
            Activation::Relu => row.iter_mut().for_each(|v| *v = (*v * scale + shift).max(0.0)),
            Activation::Leaky(slope) => row.iter_mut().for_each(|v| {
                let slope = slope as f32;
                let y = *v * scale + shift;
                *v = if y >= 0.0 { y } else { y * slope };
            }),
        }
    }
}

/// A pointer that rayon tasks may share to write disjoint parts of one buffer.
#[derive(Clone, Copy)]
pub(crate) struct SharedMut(pub(crate) *mut f32);
// SAFETY: a `SharedMut` is only made from a `&mut [f32]` that outlives the parallel loop using
// it (`conv_forward::forward_image`, `winograd::forward_image` and `transform_rows`), and each
// task writes only its own disjoint columns or rows, so sending the pointer to another thread
// creates no aliasing writes.
unsafe impl Send for SharedMut {}
// SAFETY: as for `Send`: shared references to it only ever copy the pointer out, and every write
// through the copies goes to a range no other task touches.
unsafe impl Sync for SharedMut {}

impl SharedMut {
    /// Through a method, so that closures capture the whole (Send) wrapper, not the raw field.
    pub(crate) fn at(self, offset: usize) -> *mut f32 {
        self.0.wrapping_add(offset)
    }
}

/// A cache line, in bytes.
const LINE: usize = 64;

/// `len` values of `buf` from its first cache-line boundary on, `buf` grown as needed (its
/// values are whatever it held: callers write before they read). A scratch whose rows are a
/// multiple of sixteen values long then starts every row on a line, so that each AVX-512 load
/// and store of a row touches one line, not two (F(4x4, 3x3)'s transformed input and products:
/// a dense layer's 3x3 convolution 1.3x faster, BENCHMARKS.md).
pub(crate) fn aligned(buf: &mut Vec<f32>, len: usize) -> &mut [f32] {
    let spare = LINE / std::mem::size_of::<f32>();
    if buf.len() < len + spare {
        buf.resize(len + spare, 0.0);
    }
    // `align_offset` may answer "cannot" (usize::MAX); the values are then only unaligned.
    let offset = Some(buf.as_ptr().align_offset(LINE)).filter(|o| *o < spare).unwrap_or(0);
    &mut buf[offset..offset + len]
}

/// Splits `n` columns (or rows) into ranges of at most `max`, about two per thread where each
/// still holds `min`, their count a multiple of the threads once there are as many, their sizes
/// one apart at most. Against `column_chunks`: no thread waits on a last task of its own (five
/// tasks on two threads), and a small image is not cut into many narrow products that each
/// pack the whole weight again (a dense layer's 1x1 convolution at 15x20 in four tasks of 75
/// columns took 1.2x its time in two of 150, BENCHMARKS.md).
pub(crate) fn balanced_chunks(n: usize, min: usize, max: usize) -> Vec<std::ops::Range<usize>> {
    let threads = rayon::current_num_threads().max(1);
    let mut tasks = n.div_ceil(max.max(1)).max((2 * threads).min(n / min.max(1))).max(1);
    if tasks >= threads {
        tasks = tasks.next_multiple_of(threads);
    }
    let tasks = tasks.min(n.max(1));
    let mut start = 0;
    (0..tasks)
        .map(|i| {
            let size = n / tasks + usize::from(i < n % tasks);
            start += size;
            start - size..start
        })
        .filter(|r| !r.is_empty())
        .collect()
}

/// Splits `n` columns into ranges of at most `max` and about two per thread, none narrower than
/// `min` unless `n` is.
pub(crate) fn column_chunks(n: usize, min: usize, max: usize) -> Vec<std::ops::Range<usize>> {
    let want = (2 * rayon::current_num_threads()).max(1);
    let size = n.div_ceil(want).clamp(min, max.max(min)).min(n.max(1));
    (0..n).step_by(size).map(|start| start..(start + size).min(n)).collect()
}

/// `dst[m, n] (+)= lhs[m, k] * rhs[k, n]` with element strides (column, row) for each matrix.
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn matmul(
    [m, n, k]: [usize; 3],
    dst: *mut f32,
    [dst_cs, dst_rs]: [usize; 2],
    accumulate: bool,
    lhs: *const f32,
    [lhs_cs, lhs_rs]: [usize; 2],
    rhs: *const f32,
    [rhs_cs, rhs_rs]: [usize; 2],
) {
    // SAFETY: the callers pass pointers and strides that stay inside their buffers.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            dst_cs as isize,
            dst_rs as isize,
            accumulate,
            lhs,
            lhs_cs as isize,
            lhs_rs as isize,
            rhs,
            rhs_cs as isize,
            rhs_rs as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        )
    }
}

/// A Winograd-transformed weight (`winograd`, `winograd4`): `products` matrices [channels_out, channels_in], `u[xi * o * c + oc *
/// c + ic]`, the output channels in parallel, each one's rows computed by `rows(oc, runs)` into
/// `runs[xi * c + ic]` and copied out whole.
pub(crate) fn transform_rows(o: usize, c: usize, products: usize, rows: impl Fn(usize, &mut [f32]) + Sync) -> Vec<f32> {
    let mut u = vec![0.0f32; products * o * c];
    let dst = SharedMut(u.as_mut_ptr());
    rayon::prelude::IntoParallelIterator::into_par_iter(0..o).for_each(|oc| {
        let mut runs = vec![0.0f32; products * c];
        rows(oc, &mut runs);
        for (xi, run) in runs.chunks_exact(c.max(1)).enumerate() {
            // SAFETY: row `oc` of matrix `xi` of `u`, written by this task alone.
            unsafe { std::ptr::copy_nonoverlapping(run.as_ptr(), dst.at(xi * o * c + oc * c), c) };
        }
    });
    u
}

/// A convolution's input read row by row ([channels, height, width]): the kernels that take it
/// read each row once per task, so an input that is computed (an upsampled and concatenated
/// one, `upsample::upsample_concat_conv`) need never be written whole.
pub(crate) trait InputRows: Sync {
    /// Row `y` of channel `channel` (`width` values), computed into `scratch` where it must be.
    fn row<'a>(&'a self, channel: usize, y: usize, scratch: &'a mut RowScratch) -> &'a [f32];
}

/// A task's scratch for `InputRows::row`, kept between its calls (and made anew for each
/// task, so nothing in it outlives the input it was computed from): the computed row, and what
/// an input computes it from with a key naming each part, so that a part the next row shares
/// (an upsampled row's two widened source rows, each read by two or three output rows in turn)
/// is computed once per task instead of once per output row.
#[derive(Default)]
pub(crate) struct RowScratch {
    pub(crate) values: Vec<f32>,
    /// What each of the parts in `values` holds (`None`: nothing yet).
    pub(crate) keys: [Option<(usize, usize)>; 2],
}

/// An input held whole: `image` [channels, height, width].
pub(crate) struct Planes<'a> {
    pub(crate) image: &'a [f32],
    pub(crate) height: usize,
    pub(crate) width: usize,
}

impl InputRows for Planes<'_> {
    #[inline(always)]
    fn row<'a>(&'a self, channel: usize, y: usize, _: &'a mut RowScratch) -> &'a [f32] {
        &self.image[(channel * self.height + y) * self.width..][..self.width]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ranges cover every column once, in order, none over the cap, their sizes one apart at
    /// most, their count a multiple of the threads once it reaches them, and none narrower than
    /// `min` where a split was optional (fewer ranges than `max` alone asks are never made).
    #[test]
    fn balanced_chunks_cover_the_columns_evenly() {
        let threads = rayon::current_num_threads().max(1);
        for n in [0usize, 1, 2, 3, 5, 8, 15, 30, 60, 61, 300, 1200, 19200] {
            for (min, max) in [(1usize, 1usize), (1, 3), (4, 6), (1, 12), (128, 512), (64, 100)] {
                let chunks = balanced_chunks(n, min, max);
                let mut next = 0;
                for c in &chunks {
                    assert_eq!(c.start, next, "n {n} min {min} max {max}: {chunks:?}");
                    assert!(!c.is_empty() && c.len() <= max, "n {n} min {min} max {max}: {chunks:?}");
                    next = c.end;
                }
                assert_eq!(next, n, "n {n} min {min} max {max}: {chunks:?}");
                let sizes: Vec<usize> = chunks.iter().map(|c| c.len()).collect();
                assert!(sizes.windows(2).all(|w| w[0] >= w[1] && w[0] - w[1] <= 1), "{n} {min} {max}: {chunks:?}");
                if chunks.len() >= threads && n >= chunks.len().next_multiple_of(threads) {
                    assert_eq!(chunks.len() % threads, 0, "n {n} min {min} max {max}: {chunks:?}");
                }
                if chunks.len() > n.div_ceil(max) {
                    assert!(sizes.iter().all(|&s| s + 1 >= min), "n {n} min {min} max {max}: {chunks:?}");
                }
            }
        }
    }

    /// The slice is as long as asked, starts on a cache line inside the buffer (buffers of many
    /// sizes, which the allocator starts at various offsets of a line), and a buffer long enough
    /// already keeps its length and place.
    #[test]
    fn aligned_starts_on_a_line() {
        let mut held = Vec::new();
        for size in 0..200usize {
            for len in [0usize, 1, 15, 16, 17, 1000] {
                let mut buf = vec![0.0f32; size];
                let got = aligned(&mut buf, len);
                assert_eq!(got.len(), len);
                assert_eq!(got.as_ptr() as usize % LINE, 0, "size {size} len {len}");
                got.fill(1.0);
                let (start, capacity) = (buf.as_ptr() as usize, buf.len());
                let again = aligned(&mut buf, len).as_ptr() as usize;
                assert_eq!((buf.as_ptr() as usize, buf.len()), (start, capacity), "size {size} len {len}");
                assert!(again >= start && again + 4 * len <= start + 4 * capacity);
                held.push(buf);
            }
        }
    }
}
