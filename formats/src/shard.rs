//! One machine's share of a job that many run at once (`--shard K/N`): a job array's task
//! generates or labels the items whose id is `K` modulo `N`, and `dataset merge` puts the shares
//! back together as the dataset one run would have written.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Share `index` of `count` (0-based, as Slurm's `SLURM_ARRAY_TASK_ID` for `--array=0-(N-1)`
/// and Kubernetes' `JOB_COMPLETION_INDEX` count).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

impl Shard {
    /// Whether item `id` is this share's: ids are dealt round-robin, so that every share gets
    /// as many items as the others (to one) and a like mix of them.
    pub fn holds(&self, id: u32) -> bool {
        id % self.count == self.index
    }

    /// Whether `shard` (or no shard: the whole job) holds item `id`.
    pub fn includes(shard: Option<Shard>, id: u32) -> bool {
        shard.is_none_or(|s| s.holds(id))
    }

    /// The ids of `0..count` that `shard` (or no shard: the whole job) holds, in order.
    pub fn ids(shard: Option<Shard>, count: u32) -> impl Iterator<Item = u32> {
        (0..count).filter(move |&id| Shard::includes(shard, id))
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = String;

    /// `K/N`: share `K` (0-based) of `N`.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let bad = || format!("{text:?} is not a shard: write K/N, share K (0-based) of N, e.g. 0/8 .. 7/8");
        let (k, n) = text.trim().split_once('/').ok_or_else(bad)?;
        let (index, count): (u32, u32) = (k.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if count == 0 {
            return Err(format!("{text:?}: a job cannot be cut into 0 shards"));
        }
        if index >= count {
            return Err(format!("{text:?}: shards are counted from 0, so K must be below N ({} at most)", count - 1));
        }
        Ok(Shard { index, count })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_deal_every_id_to_exactly_one_share() {
        let shards: Vec<Shard> = (0..3).map(|k| format!("{k}/3").parse().unwrap()).collect();
        for id in 0..100 {
            assert_eq!(shards.iter().filter(|s| s.holds(id)).count(), 1);
        }
        assert!(Shard::includes(None, 7) && !Shard::includes(Some(shards[0]), 7));
        assert_eq!(Shard::ids(Some(shards[1]), 8).collect::<Vec<_>>(), [1, 4, 7]);
        assert_eq!(Shard::ids(None, 3).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(shards[2].to_string(), "2/3");
        assert_eq!(" 1 / 4 ".parse::<Shard>().unwrap(), Shard { index: 1, count: 4 });
    }

    #[test]
    fn shards_that_cannot_be_are_refused_with_the_reason() {
        for (text, says) in
            [("3/3", "counted from 0"), ("0/0", "0 shards"), ("1", "K/N"), ("a/2", "K/N"), ("-1/2", "K/N")]
        {
            let e = text.parse::<Shard>().unwrap_err();
            assert!(e.contains(says), "{text}: {e}");
        }
    }
}
