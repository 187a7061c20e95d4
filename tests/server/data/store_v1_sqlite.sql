-- gyrocal store schema version 1 (as created by gyrocal 0.1.0), for the migration tests
CREATE TABLE audit_log (
	id INTEGER NOT NULL, 
	at DATETIME NOT NULL, 
	operator VARCHAR(128), 
	action VARCHAR(64) NOT NULL, 
	device_id VARCHAR(128), 
	session_id VARCHAR(64), 
	detail JSON, 
	PRIMARY KEY (id)
);

CREATE INDEX ix_audit_log_device_id ON audit_log (device_id);

CREATE TABLE devices (
	id VARCHAR(128) NOT NULL, 
	name VARCHAR(256), 
	address VARCHAR(128), 
	transport VARCHAR(32), 
	sensor_model VARCHAR(128), 
	firmware VARCHAR(128), 
	serial VARCHAR(128), 
	first_seen DATETIME NOT NULL, 
	last_seen DATETIME NOT NULL, 
	PRIMARY KEY (id)
);

CREATE TABLE operators (
	id INTEGER NOT NULL, 
	name VARCHAR(128) NOT NULL, 
	secret_hash VARCHAR(512) NOT NULL, 
	created_at DATETIME NOT NULL, 
	disabled_at DATETIME, 
	PRIMARY KEY (id), 
	UNIQUE (name)
);

CREATE TABLE schema_info (
	id INTEGER NOT NULL, 
	version INTEGER NOT NULL, 
	migrated_at DATETIME NOT NULL, 
	PRIMARY KEY (id)
);

CREATE TABLE sessions (
	id VARCHAR(64) NOT NULL, 
	device_id VARCHAR(128) NOT NULL, 
	kind VARCHAR(16) NOT NULL, 
	state VARCHAR(32) NOT NULL, 
	reason_code VARCHAR(64), 
	reason TEXT, 
	method VARCHAR(32) NOT NULL, 
	operator VARCHAR(128), 
	started_at DATETIME NOT NULL, 
	ended_at DATETIME, 
	result JSON, 
	passed BOOLEAN, 
	decision VARCHAR(16), 
	decided_at DATETIME, 
	decided_by VARCHAR(128), 
	software_version VARCHAR(32) NOT NULL, 
	info JSON, 
	PRIMARY KEY (id)
);

CREATE INDEX ix_sessions_device_id ON sessions (device_id);

CREATE TABLE auth_tokens (
	token_hash VARCHAR(64) NOT NULL, 
	operator_id INTEGER NOT NULL, 
	created_at DATETIME NOT NULL, 
	expires_at DATETIME NOT NULL, 
	revoked_at DATETIME, 
	PRIMARY KEY (token_hash), 
	FOREIGN KEY(operator_id) REFERENCES operators (id)
);

CREATE TABLE calibrations (
	id INTEGER NOT NULL, 
	device_id VARCHAR(128) NOT NULL, 
	session_id VARCHAR(64) NOT NULL, 
	k_x FLOAT NOT NULL, 
	k_y FLOAT NOT NULL, 
	k_z FLOAT NOT NULL, 
	b_x FLOAT NOT NULL, 
	b_y FLOAT NOT NULL, 
	b_z FLOAT NOT NULL, 
	uncertainty JSON, 
	quality JSON, 
	result JSON NOT NULL, 
	method VARCHAR(32) NOT NULL, 
	software_version VARCHAR(32) NOT NULL, 
	sensor_model VARCHAR(128), 
	firmware VARCHAR(128), 
	operator VARCHAR(128) NOT NULL, 
	recording_sha256 VARCHAR(64), 
	computed_at DATETIME NOT NULL, 
	accepted_at DATETIME NOT NULL, 
	PRIMARY KEY (id), 
	FOREIGN KEY(session_id) REFERENCES sessions (id)
);

CREATE INDEX ix_calibrations_device_id ON calibrations (device_id);

CREATE TABLE recordings (
	id INTEGER NOT NULL, 
	session_id VARCHAR(64) NOT NULL, 
	sha256 VARCHAR(64) NOT NULL, 
	encoding VARCHAR(32) NOT NULL, 
	n_samples INTEGER NOT NULL, 
	size_bytes INTEGER NOT NULL, 
	data BLOB NOT NULL, 
	created_at DATETIME NOT NULL, 
	PRIMARY KEY (id), 
	UNIQUE (session_id), 
	FOREIGN KEY(session_id) REFERENCES sessions (id)
);

CREATE TRIGGER IF NOT EXISTS calibrations_no_update BEFORE UPDATE ON calibrations BEGIN SELECT RAISE(ABORT, 'calibrations is append-only'); END;

CREATE TRIGGER IF NOT EXISTS calibrations_no_delete BEFORE DELETE ON calibrations BEGIN SELECT RAISE(ABORT, 'calibrations is append-only'); END;

CREATE TRIGGER IF NOT EXISTS recordings_no_update BEFORE UPDATE ON recordings BEGIN SELECT RAISE(ABORT, 'recordings is append-only'); END;

CREATE TRIGGER IF NOT EXISTS recordings_no_delete BEFORE DELETE ON recordings BEGIN SELECT RAISE(ABORT, 'recordings is append-only'); END;

CREATE TRIGGER IF NOT EXISTS audit_log_no_update BEFORE UPDATE ON audit_log BEGIN SELECT RAISE(ABORT, 'audit_log is append-only'); END;

CREATE TRIGGER IF NOT EXISTS audit_log_no_delete BEFORE DELETE ON audit_log BEGIN SELECT RAISE(ABORT, 'audit_log is append-only'); END;
