//! Allocator tuning for the project's programs.

/// Keeps freed memory in the process for reuse instead of handing big blocks back to the kernel
/// at every free. glibc serves blocks above its mmap threshold (128 KiB at start) with fresh
/// mappings and trims the heap's top eagerly, so a loop that allocates and frees the same
/// megabyte buffers for every sample (the ray caster's triangles, depth maps, images, tensors)
/// pays a page fault per 4 KiB each time: about a tenth of a generated sample's time here.
/// Call once at the start of `main`; returns whether the settings were taken (always false
/// off glibc, where it does nothing).
pub fn keep_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // Blocks up to 512 MiB come from the heap (DenseDepth-161's largest activations at
        // 480x640 are 72 MB: faulting in fresh pages for one took 54 ms against 10 ms reusing
        // the heap's); the heap's free top is never handed back (-1: the programs' peaks recur,
        // every train step frees and reallocates its 2.6 GB of activations at 480x640), and
        // the heap grows 16 MiB at a time.
        // SAFETY: glibc documents mallopt as safe to call at any time from any thread: it only
        // sets allocator parameters, under the arena locks.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, 512 << 20) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, -1) == 1
                && libc::mallopt(libc::M_TOP_PAD, 16 << 20) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_the_settings() {
        assert!(super::keep_freed_memory());
        // Memory still works both sides of the new threshold.
        let big = vec![1u8; 600 << 20];
        let small = vec![2u8; 1 << 20];
        assert_eq!(big.iter().map(|&b| b as usize).sum::<usize>() + small[0] as usize, (600 << 20) + 2);
    }
}
