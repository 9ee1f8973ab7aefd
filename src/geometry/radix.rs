//! Stable LSD radix sort of `u64` keys on a range of their bits (used by voxel and grid builders).

/// Sorts `keys` ascending by bits `[low_bit, 64)`, stably, so elements equal there keep their order.
/// Bits below `low_bit` are assumed to be already in ascending input order (they carry the index).
pub(crate) fn radix_sort_high_bits(keys: &mut Vec<u64>, low_bit: u32, high_bit: u32) {
    const DIGIT: u32 = 11;
    const BUCKETS: usize = 1 << DIGIT;
    if keys.len() < 2 || high_bit <= low_bit {
        return;
    }
    let mut tmp = vec![0u64; keys.len()];
    let mut shift = low_bit;
    while shift < high_bit {
        let mut counts = [0usize; BUCKETS];
        for &k in keys.iter() {
            counts[((k >> shift) as usize) & (BUCKETS - 1)] += 1;
        }
        if counts.iter().any(|&c| c == keys.len()) {
            shift += DIGIT; // every key has the same digit: this pass would not move anything
            continue;
        }
        let mut sum = 0;
        for c in counts.iter_mut() {
            let n = *c;
            *c = sum;
            sum += n;
        }
        for &k in keys.iter() {
            let d = ((k >> shift) as usize) & (BUCKETS - 1);
            tmp[counts[d]] = k;
            counts[d] += 1;
        }
        std::mem::swap(keys, &mut tmp);
        shift += DIGIT;
    }
}

/// Number of bits needed to hold values `0..=max`.
pub(crate) fn bits_for(max: u64) -> u32 {
    64 - max.leading_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn matches_std_sort() {
        let mut r = Rng::new(3);
        for n in [0usize, 1, 2, 17, 5000] {
            let idx_bits = bits_for(n as u64);
            let mut keys: Vec<u64> = (0..n as u64).map(|i| ((r.next_u64() % 1000) << idx_bits) | i).collect();
            let mut expected = keys.clone();
            expected.sort();
            radix_sort_high_bits(&mut keys, idx_bits, idx_bits + 10);
            assert_eq!(keys, expected);
        }
    }
}
