"""results, selections, retired: the first schema of the results database.

Revision ID: 0001
Revises:
"""
from alembic import op
import sqlalchemy as sa

revision = '0001'
down_revision = None
branch_labels = None
depends_on = None

NAME = sa.String(128)


def upgrade() -> None:
    op.create_table(
        'results',
        sa.Column('cell', NAME, primary_key=True),
        sa.Column('kind', sa.String(32), primary_key=True),
        sa.Column('id', NAME, primary_key=True),
        sa.Column('scope', NAME, nullable=False),
        sa.Column('stamp_ns', sa.BigInteger, nullable=False),
        sa.Column('method', NAME, nullable=False),
        sa.Column('gate_problem', sa.Text, nullable=False),
        sa.Column('robot_model', NAME, nullable=False),
        sa.Column('robot_serial', NAME, nullable=False),
        sa.Column('model_hash', sa.String(64), nullable=False),
        sa.Column('software_version', sa.String(64), nullable=False),
        sa.Column('bag_sha256', sa.String(64), nullable=False),
        sa.Column('temperature_c', sa.Float, nullable=True),
        sa.Column('body', sa.Text, nullable=False),
        sa.Column('written_ns', sa.BigInteger, nullable=False))
    op.create_index('results_by_time', 'results', ['cell', 'kind', 'stamp_ns'])
    op.create_table(
        'selections',
        sa.Column('cell', NAME, primary_key=True),
        sa.Column('kind', sa.String(32), primary_key=True),
        sa.Column('scope', NAME, primary_key=True),
        sa.Column('active_id', NAME, nullable=False))
    op.create_table(
        'retired',
        sa.Column('cell', NAME, primary_key=True),
        sa.Column('kind', sa.String(32), primary_key=True),
        sa.Column('id', NAME, primary_key=True))


def downgrade() -> None:
    op.drop_table('retired')
    op.drop_table('selections')
    op.drop_index('results_by_time', 'results')
    op.drop_table('results')
