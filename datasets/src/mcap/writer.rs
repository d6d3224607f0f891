//! Writing MCAP logs, in one place: the file is written as a temporary sibling, renamed
//! into place when complete and removed on error; channels are added with their schema;
//! messages are stamped in nanoseconds and numbered per channel.

use super::schema::Ros2Type;
use crate::error::DatasetError;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use stride_output::fs::temp_path_for;

/// An MCAP log being written (see [`write_log`]).
pub(super) struct LogWriter {
    writer: ::mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    sequences: BTreeMap<u16, u32>,
}

impl LogWriter {
    fn err(&self, e: ::mcap::McapError) -> DatasetError {
        DatasetError::invalid(&self.path, format!("writing MCAP: {e}"))
    }

    /// Adds a channel on `topic` whose messages are `message_encoding`, with the schema
    /// `name` (`schema_encoding`, `schema`) and the channel's `metadata`.
    pub fn add_channel(
        &mut self,
        name: &str,
        schema_encoding: &str,
        schema: &[u8],
        topic: &str,
        message_encoding: &str,
        metadata: &[(&str, String)],
    ) -> Result<u16, DatasetError> {
        let id = self
            .writer
            .add_schema(name, schema_encoding, schema)
            .map_err(|e| self.err(e))?;
        let meta: BTreeMap<String, String> = metadata
            .iter()
            .map(|(k, v)| ((*k).to_owned(), v.clone()))
            .collect();
        self.writer
            .add_channel(id, topic, message_encoding, &meta)
            .map_err(|e| self.err(e))
    }

    /// Adds a channel of ROS 2 messages (CDR, `ros2msg` schema) of type `ty` on `topic`.
    pub fn add_ros2_channel(
        &mut self,
        ty: Ros2Type,
        topic: &str,
        metadata: &[(&str, String)],
    ) -> Result<u16, DatasetError> {
        let text = ty.schema_text();
        self.add_channel(
            ty.name(),
            "ros2msg",
            text.as_bytes(),
            topic,
            "cdr",
            metadata,
        )
    }

    /// Writes a message on `channel` logged and published at `time_ns`.
    pub fn write(&mut self, channel: u16, time_ns: u64, data: &[u8]) -> Result<(), DatasetError> {
        let sequence = self.sequences.entry(channel).or_insert(0);
        *sequence += 1;
        let header = ::mcap::records::MessageHeader {
            channel_id: channel,
            sequence: *sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| self.err(e))
    }
}

/// Writes the log at `path` with `options` (the library name is set here): `fill` adds its
/// channels and messages; the file appears at `path` only when complete.
pub(super) fn write_log<T>(
    path: &Path,
    options: ::mcap::WriteOptions,
    fill: impl FnOnce(&mut LogWriter) -> Result<T, DatasetError>,
) -> Result<T, DatasetError> {
    let tmp = temp_path_for(path);
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| DatasetError::io(&tmp, e))?;
        let writer = options
            .library(concat!("stride ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| DatasetError::invalid(path, format!("writing MCAP: {e}")))?;
        let mut log = LogWriter {
            writer,
            path: path.to_path_buf(),
            sequences: BTreeMap::new(),
        };
        let out = fill(&mut log)?;
        log.writer.finish().map_err(|e| log.err(e))?;
        let mut inner = log.writer.into_inner();
        inner.flush().map_err(|e| DatasetError::io(&tmp, e))?;
        inner
            .get_ref()
            .sync_all()
            .map_err(|e| DatasetError::io(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| DatasetError::io(path, e))?;
        Ok(out)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
