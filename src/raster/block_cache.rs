//! A memory-bounded cache of decoded blocks, shared by all tiles of a layer.
//! Least-recently-used blocks are evicted once the decoded bytes exceed the
//! budget, so windows can be read repeatedly (rendering, re-rendering after
//! each deformation) without decoding the same blocks again.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use tiff::decoder::DecodingResult;

/// (tile index, block index)
pub type BlockKey = (usize, u32);

struct Inner {
    map: HashMap<BlockKey, (Arc<DecodingResult>, u64, usize)>,
    order: BTreeMap<u64, BlockKey>,
    clock: u64,
    bytes: usize,
}

/// LRU cache of decoded blocks under a byte budget.
pub struct BlockCache {
    inner: Mutex<Inner>,
    budget: usize,
}

impl BlockCache {
    pub fn new(budget_bytes: usize) -> Self {
        BlockCache {
            inner: Mutex::new(Inner {
                map: HashMap::new(),
                order: BTreeMap::new(),
                clock: 0,
                bytes: 0,
            }),
            budget: budget_bytes,
        }
    }

    /// The byte budget.
    pub fn budget(&self) -> usize {
        self.budget
    }

    pub fn get(&self, key: BlockKey) -> Option<Arc<DecodingResult>> {
        let mut g = self.inner.lock().ok()?;
        g.clock += 1;
        let now = g.clock;
        let (block, old) = {
            let e = g.map.get_mut(&key)?;
            let old = e.1;
            e.1 = now;
            (e.0.clone(), old)
        };
        g.order.remove(&old);
        g.order.insert(now, key);
        Some(block)
    }

    pub fn insert(&self, key: BlockKey, block: Arc<DecodingResult>) {
        let size = crate::raster::sample_type::decoded_bytes(&block);
        if size > self.budget {
            return;
        }
        let Ok(mut g) = self.inner.lock() else { return };
        g.clock += 1;
        let now = g.clock;
        if let Some((_, t, s)) = g.map.insert(key, (block, now, size)) {
            g.order.remove(&t);
            g.bytes -= s;
        }
        g.order.insert(now, key);
        g.bytes += size;
        while g.bytes > self.budget {
            let Some((&t, &k)) = g.order.iter().next() else {
                break;
            };
            g.order.remove(&t);
            if let Some((_, _, s)) = g.map.remove(&k) {
                g.bytes -= s;
            }
        }
    }

    /// Forget every block of tile `tile` (after it was rewritten).
    pub fn invalidate_tile(&self, tile: usize) {
        let Ok(mut g) = self.inner.lock() else { return };
        let keys: Vec<BlockKey> = g.map.keys().filter(|k| k.0 == tile).copied().collect();
        for k in keys {
            if let Some((_, t, s)) = g.map.remove(&k) {
                g.order.remove(&t);
                g.bytes -= s;
            }
        }
    }
}
