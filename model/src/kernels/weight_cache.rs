//! Winograd-transformed weights of small convolutions, kept between calls.
//!
//! The transform `U = G g Gt` of a 3x3 weight is cheap next to a large convolution but not next
//! to a small one: on the quickstart's network at batch 1 each dense layer's and decoder block's
//! transform (a rayon scatter of its own) ran on every forward, about a twentieth of the time
//! (BENCHMARKS.md). Entries are found by the weight's address and checked against a copy of its
//! values bit for bit, so a weight that changed in place (training) or a new weight at a reused
//! address is transformed again, never served stale. Only small weights are kept, and few: the
//! large network's transforms are a negligible share of its convolutions.

use std::sync::{Arc, Mutex};

/// Largest weight kept (values): the quickstart's network's 3x3 weights are under a tenth of it,
/// DenseNet-161's dense layers' (82,944) are over it.
const MAX_WEIGHT: usize = 65536;
/// Entries kept, and the values they hold (weights and transforms, 16 MB): the least recently
/// used dropped first. A training run, whose weights change every step, keeps no more than this.
const MAX_ENTRIES: usize = 64;
const MAX_VALUES: usize = 4 << 20;

struct Entry {
    address: usize,
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
/// transformed before.
pub(super) fn transformed(weight: &[f32], transform: impl FnOnce() -> Vec<f32>) -> Arc<[f32]> {
    transformed_in(&CACHE, weight, transform)
}

/// [`transformed`] through `cache`.
fn transformed_in(cache: &Mutex<Cache>, weight: &[f32], transform: impl FnOnce() -> Vec<f32>) -> Arc<[f32]> {
    if weight.len() > MAX_WEIGHT {
        return transform().into();
    }
    let address = weight.as_ptr() as usize;
    let find =
        |cache: &Cache| cache.entries.iter().position(|e| e.address == address && e.weight.len() == weight.len());
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
    cache.entries.push(Entry { address, weight: weight.to_vec(), transformed: transformed.clone(), used: now });
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
        let transformed = |w: &[f32], t: &dyn Fn() -> Vec<f32>| transformed_in(&cache, w, t);
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
        let large = vec![1.0f32; MAX_WEIGHT + 1];
        let _ = transformed(&large, &|| transform(&large));
        let _ = transformed(&large, &|| transform(&large));
        assert_eq!(calls.get(), 5);
    }
}
