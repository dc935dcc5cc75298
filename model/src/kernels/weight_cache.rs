//! Winograd-transformed weights, kept between calls.
//!
//! The transform `U = G g Gt` of a 3x3 weight is cheap next to a large convolution but not next
//! to a small one: on the quickstart's network at batch 1 each dense layer's and decoder block's
//! transform (a rayon scatter of its own) ran on every forward, about a twentieth of the time.
//! Nor is it cheap for a large weight: DenseNet-161's decoder's largest (552 x 1488 x 3 x 3)
//! transforms into 52 MB for F(2x2, 3x3), 118 MB for F(4x4, 3x3), fresh memory on every call:
//! the transform took 43 and 89 ms, mostly the page faults of that memory's first touch, against
//! 31 and 26 ms for the rest of the convolution (BENCHMARKS.md, "F(4x4, 3x3)"). Entries are found by the weight's address and the transform's
//! kind and checked against a copy of the weight's values bit for bit, so a weight that changed
//! in place (training) or a new weight at a reused address is transformed again, never served
//! stale.

use std::sync::{Arc, Mutex};

/// Largest weight kept (values): DenseNet-161's decoder's largest is under half of it.
const MAX_WEIGHT: usize = 16 << 20;
/// Entries kept, and the values they hold (weights and transforms, 512 MiB, of which the paper's
/// network at 480x640 takes 364): the least recently used dropped first. A training run,
/// whose weights change every step, keeps no more than this.
const MAX_ENTRIES: usize = 256;
const MAX_VALUES: usize = 128 << 20;

struct Entry {
    address: usize,
    /// Which transform (the Winograd tile's side): one weight may be kept under each.
    kind: usize,
    weight: Vec<f32>,
    transformed: Arc<[f32]>,
    used: u64,
}

struct Cache {
    entries: Vec<Entry>,
    clock: u64,
}

/// The process's cache.
static CACHE: Mutex<Cache> = Mutex::new(Cache { entries: Vec::new(), clock: 0 });

/// `cache`, locked. A poisoned lock only means another thread panicked while holding it; the
/// entries are whole either way (each is removed or pushed in one step).
fn lock(cache: &Mutex<Cache>) -> std::sync::MutexGuard<'_, Cache> {
    cache.lock().unwrap_or_else(|e| e.into_inner())
}

/// Compared in blocks without stopping early inside one, so that the compare is vectorised
/// (value by value it was a tenth of a small convolution's time).
fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len()
        && a.chunks(256)
            .zip(b.chunks(256))
            .all(|(x, y)| x.iter().zip(y).fold(true, |same, (p, q)| same & (p.to_bits() == q.to_bits())))
}

/// `transform(weight)`, from the cache when this weight (same address, same values) was
/// transformed before by the transform `kind`.
pub(super) fn transformed(weight: &[f32], kind: usize, transform: impl FnOnce() -> Vec<f32>) -> Arc<[f32]> {
    transformed_in(&CACHE, weight, kind, transform)
}

/// [`transformed`] through `cache`.
fn transformed_in(
    cache: &Mutex<Cache>,
    weight: &[f32],
    kind: usize,
    transform: impl FnOnce() -> Vec<f32>,
) -> Arc<[f32]> {
    if weight.len() > MAX_WEIGHT {
        return transform().into();
    }
    let address = weight.as_ptr() as usize;
    let find = |cache: &Cache| {
        cache.entries.iter().position(|e| e.address == address && e.kind == kind && e.weight.len() == weight.len())
    };
    {
        let mut cache = lock(cache);
        cache.clock += 1;
        let now = cache.clock;
        if let Some(i) = find(&cache)
            && same_bits(&cache.entries[i].weight, weight)
        {
            cache.entries[i].used = now;
            return cache.entries[i].transformed.clone();
        }
    }
    // Transformed without the lock: the transform scatters over rayon's pool, whose workers may
    // be waiting for the lock in other convolutions of their own.
    let transformed: Arc<[f32]> = transform().into();
    let mut cache = lock(cache);
    cache.clock += 1;
    let now = cache.clock;
    if let Some(i) = find(&cache) {
        cache.entries.swap_remove(i);
    }
    let values = |e: &Entry| e.weight.len() + e.transformed.len();
    let adding = weight.len() + transformed.len();
    while cache.entries.len() >= MAX_ENTRIES
        || (!cache.entries.is_empty() && cache.entries.iter().map(values).sum::<usize>() + adding > MAX_VALUES)
    {
        let oldest = (0..cache.entries.len()).min_by_key(|&i| cache.entries[i].used).expect("entries left");
        cache.entries.swap_remove(oldest);
    }
    cache.entries.push(Entry { address, kind, weight: weight.to_vec(), transformed: transformed.clone(), used: now });
    transformed
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A weight changed in place is transformed again; an unchanged one is not; a large one is
    /// never kept.
    #[test]
    fn a_weight_is_served_from_the_cache_only_while_its_values_are_the_same() {
        // A cache of its own: tests running beside it fill the process's.
        let cache = Mutex::new(Cache { entries: Vec::new(), clock: 0 });
        let transformed = |w: &[f32], t: &dyn Fn() -> Vec<f32>| transformed_in(&cache, w, 2, t);
        let mut weight = vec![1.5f32; 90];
        let calls = std::cell::Cell::new(0);
        let transform = |w: &[f32]| {
            calls.set(calls.get() + 1);
            w.iter().map(|v| v * 2.0).collect::<Vec<f32>>()
        };
        let first = transformed(&weight, &|| transform(&weight));
        let again = transformed(&weight, &|| transform(&weight));
        assert_eq!((calls.get(), &first[..3], &again[..3]), (1, &[3.0f32; 3][..], &[3.0f32; 3][..]));
        weight[7] = -0.0;
        let changed = transformed(&weight, &|| transform(&weight));
        assert_eq!((calls.get(), changed[7].to_bits()), (2, (-0.0f32).to_bits()));
        // -0.0 and 0.0 compare equal as numbers, not as bits: the cache tells them apart.
        weight[7] = 0.0;
        let _ = transformed(&weight, &|| transform(&weight));
        assert_eq!(calls.get(), 3);
        // Another transform of the same weight is kept beside it, and served as its own.
        let other = transformed_in(&cache, &weight, 4, || vec![9.0; 4]);
        assert_eq!((calls.get(), &other[..]), (3, &[9.0f32; 4][..]));
        let again = transformed(&weight, &|| transform(&weight));
        assert_eq!((calls.get(), again[0]), (3, 3.0));
        let large = vec![1.0f32; MAX_WEIGHT + 1];
        let _ = transformed(&large, &|| transform(&large));
        let _ = transformed(&large, &|| transform(&large));
        assert_eq!(calls.get(), 5);
    }
}
